"""``--odometry FILE`` (and ``--odometry-spacing``) of ``gridplace evaluate|localize
--sequence``: the vehicle's displacement per query row, from a ``.npy`` or a text file."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from service.encoding.sequence import check_odometry, odometry_in_frames
from service.errors import InvalidInputError, InvalidParameterError
from service.encoding import load_npy

OdometryOpt = Annotated[
    Path | None,
    typer.Option(
        "--odometry", metavar="FILE",
        help="with --sequence: the vehicle's displacement since the previous row, in reference "
             "frames (signed), one per query row: a float .npy, or text with one number per "
             "line (an empty line: no odometry for that row)",
    ),
]  # fmt: skip


SpacingOpt = Annotated[
    float | None,
    typer.Option(
        "--odometry-spacing", metavar="METRES",
        help="the --odometry file is in metres: METRES between consecutive reference frames",
    ),
]  # fmt: skip


def odometry_for(path: Path | None, n: int, spacing: float | None) -> np.ndarray | None:
    """``--odometry`` (and ``--odometry-spacing``) as displacements in reference frames."""
    if path is None:
        if spacing is not None:
            raise InvalidParameterError("--odometry-spacing needs --odometry")
        return None
    u = load_odometry(path, n)
    return u if spacing is None else odometry_in_frames(u, n, spacing)


def load_odometry(path: Path, n: int) -> np.ndarray:
    """Per-row displacements from ``path`` (NaN: a row without), checked for ``n`` rows."""
    if path.suffix == ".npy":
        values = np.asarray(load_npy(path), dtype=np.float64)
        if np.isnan(values).any():
            raise InvalidInputError(f"{path} contains NaN (leave a text file's line empty for a "
                                    "row without odometry)")  # fmt: skip
        return check_odometry(values, n)
    try:
        lines = path.read_text().splitlines()
    except OSError as exc:
        raise InvalidInputError(f"cannot read odometry file {path}: {exc.strerror}") from exc
    except UnicodeDecodeError:
        raise InvalidInputError(f"{path} is not a text file of numbers (or a .npy)") from None
    rows: list[float | None] = []
    for i, line in enumerate(lines, 1):
        text = line.strip()
        if not text:
            rows.append(None)
            continue
        try:
            rows.append(float(text))
        except ValueError:
            raise InvalidInputError(f"{path} line {i}: {text!r} is not a number") from None
    return check_odometry(rows, n)


