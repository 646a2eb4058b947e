"""``gridplace extract``: a folder of images → an ``.npy`` of descriptors, in file-name order."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import typer
from pydantic import ValidationError
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

from service.cli.console import cli_console, plural
from service.cli.errors import cli_errors, err_console
from service.errors import ConflictError, InvalidParameterError
from service.imaging import (
    DEFAULT_EXTRACTOR,
    PRESETS,
    extract_folder,
    list_images,
    make_extractor,
    parse_extractor_config,
)
from service.imaging.resumable import partial_dir
from service.imaging.settings import ImagingSettings

console = cli_console()


@cli_errors
def extract(
    images_dir: Annotated[Path, typer.Argument(help="folder of images (frames in file-name order)")],
    out: Annotated[Path, typer.Option("--out", "-o", help="output .npy (float32, N×d)")],
    extractor: Annotated[
        str | None, typer.Option(help=f"patchnorm | hog | cnn (default {DEFAULT_EXTRACTOR['kind']})")
    ] = None,
    preset: Annotated[
        str | None, typer.Option(help=f"cnn preset: {' | '.join(PRESETS)}")
    ] = None,
    width: Annotated[int | None, typer.Option(help="resize width (patchnorm/hog 64; cnn: input)")] = None,
    height: Annotated[int | None, typer.Option(help="resize height (patchnorm/hog 32)")] = None,
    patch: Annotated[int | None, typer.Option(help="patchnorm patch side (default 16)")] = None,
    batch_size: Annotated[
        int | None, typer.Option(min=1, max=4096, help="images per forward pass (cnn; default 32)")
    ] = None,
    device: Annotated[str | None, typer.Option(help="cnn: auto | cpu | cuda")] = None,
    threads: Annotated[
        int | None, typer.Option(min=0, max=256, help="cnn: CPU threads (default 1; 0 = all cores)")
    ] = None,
    restart: Annotated[
        bool, typer.Option(help="ignore a partial extraction left by an interrupted run")
    ] = False,
    overwrite: Annotated[
        bool, typer.Option(help="replace --out if it exists (else an existing file is refused)")
    ] = False,
) -> None:
    """Extract descriptors exactly as the server does for image uploads and image queries.

    The extractor config (with the CNN preset's name) is written beside the output as
    ``<out>.extractor.json``. An existing ``--out`` is refused unless ``--overwrite`` (it is then
    replaced only once the new array is complete). An interrupted run (Ctrl-C) resumes where
    it stopped when started again with the same folder and options (``--restart`` starts over)."""
    if (out.exists() or out.is_symlink()) and not overwrite:
        raise ConflictError(f"{out} already exists; pass --overwrite to replace it, or choose "
                            "another --out", path=str(out))  # fmt: skip
    raw: dict[str, Any] = {"kind": extractor or ("cnn" if preset else DEFAULT_EXTRACTOR["kind"])}
    options = {"width": width, "height": height, "patch": patch, "preset": preset}
    raw.update({k: v for k, v in options.items() if v is not None})
    config = parse_extractor_config(raw)
    speed = {"batch_size": batch_size, "device": device, "threads": threads}
    runtime = {f"extractor_{k}": v for k, v in speed.items() if v is not None}
    paths = list_images(images_dir)
    try:
        settings = ImagingSettings(**runtime)
    except ValidationError as exc:
        raise InvalidParameterError(f"--device: {exc.errors()[0]['msg']}") from exc
    label = getattr(config, "preset", None) or config.kind
    try:
        ext = make_extractor(config, settings)
        with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                      TimeRemainingColumn(), console=console) as bar:  # fmt: skip
            task = bar.add_task(f"{label} {images_dir.name}", total=len(paths))
            result = extract_folder(ext, paths, out, restart=restart,
                                    progress=lambda done, _n: bar.update(task, completed=done))  # fmt: skip
    except KeyboardInterrupt:
        kept = partial_dir(out)
        where = f" (the frames extracted so far are kept in {kept})" if kept.is_dir() else ""
        err_console.print(f"interrupted; run the same command again to resume{where}",
                          highlight=False, markup=False)  # fmt: skip
        raise typer.Exit(code=130) from None
    sidecar = out.with_name(out.name + ".extractor.json")
    sidecar.write_text(json.dumps(config.model_dump(mode="json"), indent=2) + "\n")
    resumed = f", resumed after {result.resumed_from}" if result.resumed_from else ""
    console.print(f"wrote {out}: {plural(result.n_frames, 'frame')} × d={result.n_features} "
                  f"({label}{resumed}); {sidecar}", highlight=False)  # fmt: skip


def register(app: typer.Typer) -> None:
    app.command()(extract)
