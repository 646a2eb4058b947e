"""``gridplace extract``: a folder of images → an ``.npy`` of descriptors, in file-name order."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

from service.cli.errors import cli_errors
from service.imaging import extract_paths, list_images, make_extractor, parse_extractor_config

console = Console()


@cli_errors
def extract(
    images_dir: Annotated[Path, typer.Argument(help="folder of images (frames in file-name order)")],
    out: Annotated[Path, typer.Option("--out", "-o", help="output .npy (float32, N×d)")],
    extractor: Annotated[str, typer.Option(help="patchnorm | hog | cnn")] = "patchnorm",
    width: Annotated[int | None, typer.Option(help="resize width (patchnorm/hog default 64)")] = None,
    height: Annotated[int | None, typer.Option(help="resize height (default 32)")] = None,
    patch: Annotated[int | None, typer.Option(help="patchnorm patch side (default 16)")] = None,
    weights: Annotated[Path | None, typer.Option(help="cnn: local torchvision weights file")] = None,
    arch: Annotated[str | None, typer.Option(help="cnn: resnet18 | resnet34 | resnet50 | …")] = None,
) -> None:
    """Extract descriptors exactly as the server does for image uploads and image queries;
    the extractor config is written beside the output as ``<out>.extractor.json``."""
    raw: dict[str, Any] = {"kind": extractor}
    for key, value in dict(width=width, height=height, patch=patch, arch=arch,
                           weights=str(weights) if weights else None).items():  # fmt: skip
        if value is not None:
            raw[key] = value
    config = parse_extractor_config(raw)
    paths = list_images(images_dir)
    ext = make_extractor(config)
    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                  TimeRemainingColumn(), console=console) as bar:  # fmt: skip
        task = bar.add_task(f"{config.kind} {images_dir.name}", total=len(paths))
        X = extract_paths(ext, paths, lambda done, _total: bar.update(task, completed=done))
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.tmp")
    with open(tmp, "wb") as fh:
        np.save(fh, X, allow_pickle=False)
    tmp.replace(out)
    sidecar = out.with_name(out.name + ".extractor.json")
    sidecar.write_text(json.dumps(config.model_dump(), indent=2) + "\n")
    console.print(f"wrote {out}: {X.shape[0]} frames × d={X.shape[1]} ({config.kind}); {sidecar}")


def register(app: typer.Typer) -> None:
    app.command()(extract)
