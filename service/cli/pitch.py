"""What gridplace is and what ships, in the words every front door uses: ``gridplace --help``,
the demo's banner, ``pyproject.toml``'s description and the top of the README (a test keeps
them, and the figures below, in agreement with :data:`DEFAULT_PRESET` and the measurements).

Figures: Nordland summer map → winter queries, the default CNN descriptors (lite0-b4,
d = 5,120), whole route, within ±5 frames, through the CLI with its defaults
(``docs/benchmarks/cli-defaults-nordland-2026-12-01.json``, ``…-adapted-…``) and ``gridplace
bench quality`` (``docs/results/quality/quality.json``). When a preset's role or the default
changes, change it here (and in the README) with the run that measured it.
"""

from __future__ import annotations

from service.encoding.presets import DEFAULT_PRESET

# pyproject.toml's description (one line) and the first line of ``gridplace --help``
SUMMARY = (
    "Visual place recognition as a service: which frame of a known route a camera sees, "
    "from an int8 prototype per frame in a learnt PCA space (default) or Le & Milford's "
    "sub-linear code (by name)"
)

# the preset the texts below describe as the default (a test compares it with DEFAULT_PRESET)
DESCRIBED_DEFAULT = "robust"

# measured figures quoted below, and where each comes from (a test re-reads them)
FIGURES = {
    "robust_single": 43.6,  # cli-defaults: gridplace single_p5
    "exact_nn_single": 41.4,  # cli-defaults: exact_nn single_p5
    "nn_pca256_single": 43.5,  # quality.json: lite0-b4, cross, nn-pca256, all, single ±5
    "robust_adapted": 53.4,  # cli-defaults-adapted: gridplace adapted single_p5
    "robust_drive": 99.0,  # cli-drive: robust sequence_precision (this filter's defaults)
    "robust_storage_pct": 3.1,  # cli-defaults: ratios storage_vs_exact_nn
    "paper_single": 1.9,  # quality.json: lite0-b4, cross, paper, all, single ±5
    "residue_single": 23.9,  # quality.json: lite0-b4, cross, residue, all, single ±5
    "residue_drive": 99.0,  # quality.json: lite0-b4, cross, residue, all, sequence ±5
    "drive_single": 12.1,  # cli-drive: drive_as_sent precision
    "drive_drive": 98.4,  # cli-drive: drive sequence_precision
    "drive_code_pct": 4.6,  # cli-drive: ratios drive_code_bytes_vs_robust
}

_WHAT_SHIPS = (
    f"What ships: the default preset `{DESCRIBED_DEFAULT}` z-scores the columns, projects them "
    "onto a whitened PCA space (256 components, fewer on short routes) and stores one int8 "
    "prototype per frame: a nearest-neighbour search whose storage grows linearly with the "
    "route (about 264 B per frame plus the projection, capped at the size of the route's "
    "descriptors as uint8). On Nordland (summer map, winter queries, CNN descriptors) it finds "
    f"{FIGURES['robust_single']} % of single frames within ±5 (exact NN "
    f"{FIGURES['exact_nn_single']} %, exact NN in the same PCA space "
    f"{FIGURES['nn_pca256_single']} %), {FIGURES['robust_adapted']} % with appearance "
    f"adaptation and {FIGURES['robust_drive']} % as a drive, in "
    f"{FIGURES['robust_storage_pct']} % of exact NN's bytes. The paper's sub-linear code "
    "(presets `paper`, `ridge`: a few classifiers per route) stays available by name; across "
    f"seasons it is near chance ({FIGURES['paper_single']} %)."
)
_CHOOSING = (
    f"Choosing: `{DESCRIBED_DEFAULT}` for maps queried in other conditions (the default); "
    f"`residue` for half its bytes at about half its single-frame precision "
    f"({FIGURES['residue_single']} %; as a drive {FIGURES['residue_drive']} %); `drive` for "
    "fleets and streams on long routes: a code that grows as the square root of the route "
    f"({FIGURES['drive_code_pct']} % of `robust`'s class bytes here), whose single frames alias "
    f"({FIGURES['drive_single']} %) but whose drives the sequence filter localises "
    f"({FIGURES['drive_drive']} %); `paper` / "
    "`ridge` to reproduce the paper; `--budget-bytes` or `--target-precision` to choose on "
    "validation queries. Details: docs/RESULTS.md."
)
# paragraphs without hard line breaks: the terminal wraps them
HELP = f"{SUMMARY}.\n\n{_WHAT_SHIPS}\n\n{_CHOOSING}"

DEMO_BANNER = (
    f"gridplace demo: the default preset `{DESCRIBED_DEFAULT}` (one int8 prototype per frame in "
    "a whitened PCA space; storage linear in the route) beside exact NN in that same space "
    "(nn-pca) and exact NN on the descriptors."
)


def demo_banner(preset: str | None) -> str:
    """The demo's first line for the preset it trains (options may choose another)."""
    if preset in (None, DESCRIBED_DEFAULT):
        return DEMO_BANNER
    return (f"gridplace demo: preset `{preset}` (chosen by your options; the default is "
            f"`{DESCRIBED_DEFAULT}`) beside exact NN on the descriptors.")
