"""What the demo's numbers mean, in a few printed lines beside its table.

Each reading is a function of the demo's results (``"<model>/<condition>"`` → the output of
:func:`service.encoding.evaluation.evaluate`) returning one line, or ``None`` when it has
nothing to say; :data:`READINGS` lists them in print order, so another comparison (a sequence
filter, another default) is one more function in that list.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

RESULTS_DOC = "docs/RESULTS.md"
TOLERANCE = 5  # frames: the "P@5" column and the server check's "correct"

Results = dict[str, dict[str, Any]]
Reading = Callable[[Results, int], str | None]


def chance(n_frames: int, tolerance: int = TOLERANCE) -> float:
    """Precision of a uniformly random answer within ``tolerance`` frames (away from the
    route's ends)."""
    return min(1.0, (2 * tolerance + 1) / max(1, n_frames))


def _p(results: Results, key: str) -> float:
    return float(results[key]["precision_at"][str(TOLERANCE)])


def _cross_season(results: Results, n_frames: int) -> str | None:
    if "gridplace/cross-season" not in results or "exact NN/cross-season" not in results:
        return None
    ours, nn = _p(results, "gridplace/cross-season"), _p(results, "exact NN/cross-season")
    verdict = "better than" if ours > nn else "equal to" if ours == nn else "below"
    return (
        f"cross-season (winter queries on the summer route, the real task; each frame adapted to "
        f"the winter frames before it, as drives are served): gridplace finds {ours:.1%} of the "
        f"frames within ±{TOLERANCE}, {verdict} exact NN's {nn:.1%} adapted the same way; a "
        f"random guess gets {chance(n_frames):.1%}."
    )


def _adaptation(results: Results, n_frames: int) -> str | None:
    del n_frames
    keys = ("gridplace/cross-season as sent", "gridplace/cross-season",
            "exact NN/cross-season as sent", "exact NN/cross-season")  # fmt: skip
    if not all(k in results for k in keys):
        return None
    p = [_p(results, k) for k in keys]
    return (
        f"appearance adaptation (each query standardised by the running mean and variance of "
        f"the frames before it; no positions used): gridplace {p[0]:.1%} → {p[1]:.1%}, exact NN "
        f"{p[2]:.1%} → {p[3]:.1%}; a /localize query without a vehicle_id is answered as sent."
    )


def _identical(results: Results, n_frames: int) -> str | None:
    del n_frames
    if "gridplace/identical" not in results:
        return None
    return (
        f"identical (the training frames themselves, an upper bound): {_p(results, 'gridplace/identical'):.1%}"
        f" within ±{TOLERANCE}; the gap to cross-season is how poorly summer-trained encoders "
        "generalise to winter."
    )


def _storage(results: Results, n_frames: int) -> str | None:
    if "gridplace/identical" not in results or "exact NN/identical" not in results:
        return None
    ours = results["gridplace/identical"]["footprint_bytes"]
    nn = results["exact NN/identical"]["footprint_bytes"]
    return (f"storage: {ours:,} B against exact NN's {nn:,} B ({nn / max(1, ours):.1f}× less; "
            f"{ours / max(1, n_frames):,.0f} B per frame at this length, fixed parts included: "
            "both grow with the route).")  # fmt: skip


def _sequence(results: Results, n_frames: int) -> str | None:
    del n_frames
    if not {"gridplace/cross-season drive", "exact NN/cross-season drive"} <= set(results):
        return None
    ours = _p(results, "gridplace/cross-season drive")
    nn = _p(results, "exact NN/cross-season drive")
    return (
        f"as one drive (the sequence filter over consecutive winter frames, its default "
        f"parameters): gridplace {ours:.1%} within ±{TOLERANCE}, exact NN {nn:.1%}."
    )


def _projection(results: Results, n_frames: int) -> str | None:
    del n_frames
    if not {"gridplace/cross-season", "nn-pca/cross-season"} <= set(results):
        return None
    ours, same = _p(results, "gridplace/cross-season"), _p(results, "nn-pca/cross-season")
    width = results["nn-pca/cross-season"].get("n_components")
    b_ours = results["gridplace/identical"]["footprint_bytes"]
    b_same = results["nn-pca/identical"]["footprint_bytes"]
    return (
        f"where the gain comes from: exact NN in the same whitened PCA-{width} space "
        f"(nn-pca{width}, float32 rows) finds {same:.1%}, gridplace {ours:.1%} — with one digit "
        f"per frame the default is that nearest-neighbour search, its rows stored as int8 "
        f"({b_ours:,} B against {b_same:,} B)."
    )


READINGS: list[Reading] = [_cross_season, _adaptation, _projection, _sequence, _identical,
                           _storage]  # fmt: skip


def verdict(results: Results) -> str | None:
    """One honest line: what fraction of exact NN's precision gridplace keeps, frame by frame
    and as a drive, for what fraction of its storage."""
    keys = ("gridplace/cross-season", "exact NN/cross-season", "gridplace/identical",
            "exact NN/identical")  # fmt: skip
    if not all(k in results for k in keys):
        return None
    ours, nn = _p(results, keys[0]), _p(results, keys[1])
    single = (f"keeps {ours / max(1e-12, nn):.0%} of exact NN's cross-season precision"
              if ours < nn else "matches or beats exact NN's cross-season precision")  # fmt: skip
    nbytes = results[keys[2]]["footprint_bytes"] / max(1, results[keys[3]]["footprint_bytes"])
    drive = ""
    if "gridplace/cross-season drive" in results and "exact NN/cross-season drive" in results:
        d_ours = _p(results, "gridplace/cross-season drive")
        d_nn = _p(results, "exact NN/cross-season drive")
        how = f"{d_ours / max(1e-12, d_nn):.0%} of it" if d_ours < d_nn else "as much or more"
        drive = f" and {how} as a drive ({d_ours:.1%} against {d_nn:.1%})"
    return (f"in short: gridplace {single} frame by frame ({ours:.1%} against {nn:.1%}){drive}, "
            f"in {nbytes:.1%} of its storage")  # fmt: skip


def reading(results: Results, n_frames: int) -> str:
    """The demo's comment on its results, ending with where the full measurements are."""
    lines = [line for read in READINGS if (line := read(results, n_frames)) is not None]
    short = verdict(results)
    lines.append(
        (f"{short}; " if short else "")
        + f"every method across conditions, measured on the whole route: {RESULTS_DOC} "
        "(Across conditions)"
    )
    return "\n".join(f"• {line}" for line in lines)


SAMPLE = 8  # winter frames the server check sends


def sample_frames(n_frames: int, count: int = SAMPLE) -> list[int]:
    """``count`` query rows evenly spaced along the route (its ends excluded)."""
    picks = np.linspace(0, n_frames - 1, count + 2)[1:-1].round().astype(int)
    return sorted({int(i) for i in picks})


def confidence_meaning(model: Any) -> str:
    """What a model's ``confidence`` is, in words."""
    if getattr(model, "chunk_encoders_", None) is not None:
        return "the joint probability of the chunk and the decoded digits"
    periods = list(getattr(model, "periods_", []))
    if len(periods) == 1:
        return (f"the calibrated softmax probability of the answered frame among all "
                f"{periods[0]:,}")  # fmt: skip
    return f"the joint probability of the {len(periods)} decoded digits"


@dataclass(frozen=True)
class ServerCheck:
    text: str
    example: int  # the query row the copy-paste examples send
    example_index: int  # the server's answer for it


def server_check(frames: list[int], answers: list[tuple[int, float]], version: int,
                 meaning: str, cross_season: float | None = None,
                 wider: tuple[int, int] | None = None) -> ServerCheck:  # fmt: skip
    """The live server's answers for ``frames`` (evenly spaced winter frames), each marked
    right or wrong, their count beside ``wider`` (hits, frames) of a larger evenly spaced
    sample and the whole drive's precision (``cross_season``), and the example frame: the
    first answered within ±TOLERANCE (else the first), said so."""
    lines = [f"server check: version {version} answered {len(frames)} winter frames evenly "
             "spaced along the route, each sent alone to /v1/localize (no vehicle, as sent):"]  # fmt: skip
    hits = []
    for frame, (index, conf) in zip(frames, answers, strict=True):
        off = abs(int(index) - int(frame))
        hits.append(off <= TOLERANCE)
        verdict = f"within ±{TOLERANCE}" if hits[-1] else f"wrong by {off:,} frames"
        lines.append(f"  frame {frame:>5} → {int(index):>5}  {verdict}, confidence {conf:.2f}")
    more = (f", {wider[0]} of {wider[1]} evenly spaced frames (one /v1/localize/batch request)"
            if wider is not None else "")  # fmt: skip
    whole = f"; on the whole winter traversal {cross_season:.1%} are" if cross_season is not None else ""
    lines.append(f"  {sum(hits)} of these {len(frames)}{more} within ±{TOLERANCE} frames{whole}. "
                 f"Confidence is {meaning}: low values mark answers not to trust.")  # fmt: skip
    pick = hits.index(True) if any(hits) else 0
    example, answer = frames[pick], int(answers[pick][0])
    why = (f"the first answered within ±{TOLERANCE}" if hits[pick]
           else f"none was answered within ±{TOLERANCE}")  # fmt: skip
    lines.append(f"  the examples below send frame {example} ({why}; the server answers {answer})")
    return ServerCheck("\n".join(lines), example, answer)
