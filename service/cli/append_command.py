"""``gridplace client append MAP V TRAVERSAL…``: append traversals to a map version without
retraining it (:mod:`service.core.appends` on the server)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from service.cli.client_job_follow import follow_job, report_job
from service.cli.client_options import (
    AsJson,
    MapName,
    Timeout,
    Token,
    Url,
    console,
    open_client,
    print_json,
)
from service.cli.console import plural
from service.cli.errors import cli_errors


@cli_errors
def append(
    map_name: MapName,
    version: Annotated[int, typer.Argument(metavar="V", help="the version appended to")],
    traversals: Annotated[list[Path], typer.Argument(
        metavar="TRAVERSAL", help=".npy/.npz descriptors of the version's width, or a .zip/.tar "
        "of images; several files are several traversals", show_default=False)],
    places: Annotated[list[Path] | None, typer.Option(
        "--places", help="int .npy: the place of every row of one traversal file (0..N-1, "
        "beyond with --extend); once per file, in the files' order", show_default=False)] = None,
    tag: Annotated[list[str] | None, typer.Option(
        "--tag", help="condition tag KEY=VALUE of the traversals (e.g. season=winter), "
        "repeatable", show_default=False)] = None,
    extend: Annotated[bool, typer.Option(help="places beyond the route extend it")] = False,
    whiten: Annotated[bool | None, typer.Option(
        "--whiten/--no-whiten", help="learn the traversals' within-place scatter (default: "
        "where the model allows it)", show_default=False)] = None,
    activate: Annotated[bool, typer.Option(help="serve the new version at once")] = False,
    retrain: Annotated[bool, typer.Option(
        "--retrain", help="instead, train a new version as a job from every traversal of V "
        "and these (an extension the code's periods cannot label), and follow the job")] = False,
    wait_timeout: Annotated[float, typer.Option(help="seconds to follow a --retrain job")] = 3600.0,
    url: Url = None,
    token: Token = None,
    timeout: Timeout = 300.0,
    as_json: AsJson = False,
) -> None:
    """Append TRAVERSAL(s) to version V of MAP without retraining: a new version (exit 2 on
    bad input: another width, places out of range, a tag that is not KEY=VALUE). With
    --retrain: a training job over every traversal instead (exit 2 if it fails)."""
    sent = traversals if len(traversals) > 1 else traversals[0]
    names = ", ".join(t.name for t in traversals)
    with open_client(url, token, timeout) as gp:
        if retrain:
            with console.status(f"uploading {names} to retrain"):
                job = gp.retrain_traversals(map_name, version, sent, places=places, tags=tag or [],
                                            extend=extend)  # fmt: skip
            report_job(gp, follow_job(gp, job, wait_timeout), as_json)
            return
        with console.status(f"appending {names}"):
            v = gp.append_traversals(map_name, version, sent, places=places, tags=tag or [],
                                     extend=extend, whiten=whiten, activate=activate)  # fmt: skip
    if as_json:
        print_json(v)
        return
    added = v.extra.get("traversals", [])[-len(traversals):]
    tags = ", ".join(f"{k}={val}" for k, val in (added[0].get("tags") or {}).items()) if added else ""
    console.print(f"{map_name} v{v.version}: v{version} + {plural(len(traversals), 'traversal')}"
                  f"{f' ({tags})' if tags else ''}, {v.n_frames:,} places, "
                  f"{v.n_traversals} traversals{', active' if v.active else ''}", highlight=False)  # fmt: skip
