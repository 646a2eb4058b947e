"""``gridplace demo``: the main job end to end on the embedded default (no Redis, no Docker).

Train on the Nordland route in ``../shared/data`` (or a clearly labelled SYNTHETIC route),
save and reload the artifact, compare with exact nearest neighbour on the winter traversal;
then (``--serve``, the default) publish the model as map ``demo`` into a data dir, start
``gridplace serve`` on it and print copy-paste ``curl``/``grpcurl``/``gridplace client`` calls.
"""

from __future__ import annotations

import base64
import json
import os
import secrets
import socket
import time
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer

from service.cli.console import cli_console
from service.cli.demo_data import EXTRACTORS, DemoData, demo_data
from service.cli.demo_examples import print_examples
from service.cli.demo_reading import (
    TOLERANCE,
    confidence_meaning,
    reading,
    sample_frames,
    server_check,
)
from service.cli.demo_table import evaluate_all
from service.cli.pitch import demo_banner
from service.cli.errors import cli_errors
from service.cli.fit_progress import fit_title, fit_with_progress
from service.encoding import (
    ModelParams,
    build_model,
    check_new_artifact_dir,
    default_trainer,
    load_model,
    save_model,
)
from service.encoding.base import PlaceRecognizer
from service.errors import InvalidParameterError, UnavailableError

console = cli_console()
DEMO_MAP = "demo"


def _fit(params: ModelParams, X: np.ndarray) -> tuple[PlaceRecognizer, float]:
    model = build_model(params)
    return model, fit_with_progress(model, X, console, fit_title(model, X.shape[0]))


def _port(wanted: int) -> int:
    """``wanted`` if it is free on 127.0.0.1, else any free port (0 = any)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        try:
            s.bind(("127.0.0.1", wanted))
        except OSError:
            s.close()
            with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as t:
                t.bind(("127.0.0.1", 0))
                chosen = int(t.getsockname()[1])
            console.print(f"[yellow]port {wanted} is in use; using {chosen}[/]")
            return chosen
        return int(s.getsockname()[1])


def _publish(data_dir: Path, model: PlaceRecognizer, params: ModelParams, data: DemoData,
             metrics: dict[str, Any]) -> int:  # fmt: skip
    from service.registry import Registry

    info = Registry(data_dir).publish(
        DEMO_MAP, model, params=params.model_dump(mode="json"), extractor=data.extractor,
        metrics=metrics, activate=True,
    )  # fmt: skip
    return info.version


def _serve(data_dir: Path, port: int, grpc_port: int, model: PlaceRecognizer, params: ModelParams,
           data: DemoData, metrics: dict[str, Any]) -> None:  # fmt: skip
    from service.api.process import ServerProcess
    from service.client import GridplaceClient

    data_dir = data_dir.resolve()
    version = _publish(data_dir, model, params, data, metrics)
    console.print(f"published map [bold]{DEMO_MAP}[/] version {version} into {data_dir}")
    token = os.environ.get("GRIDPLACE_ADMIN_TOKEN") or secrets.token_hex(16)
    port = _port(port)
    grpc_port = _port(grpc_port) if grpc_port else 0
    env = {"GRIDPLACE_ADMIN_TOKEN": token, "GRIDPLACE_GRPC_PORT": str(grpc_port),
           "GRIDPLACE_LOG_LEVEL": "info", "GRIDPLACE_TRAIN_WORKERS": "1"}  # fmt: skip
    server = ServerProcess(data_dir, env=env, port=port, log_path=data_dir / "demo-server.log")
    with console.status(f"starting gridplace serve on {server.url}"):
        server.start()
    try:
        frames, many = sample_frames(data.query.shape[0]), sample_frames(data.query.shape[0], 100)
        with GridplaceClient(server.url, token=token) as gp:
            gp.wait_until_ready(timeout=120)
            hits = [gp.localize(DEMO_MAP, data.query[i]) for i in frames]
            batch = gp.localize_batch(DEMO_MAP, data.query[many]).index
        wider = (int(np.sum(np.abs(np.asarray(batch) - np.asarray(many)) <= TOLERANCE)), len(many))
        check = server_check(frames, [(h.index, h.confidence) for h in hits], hits[0].version,
                             confidence_meaning(model), metrics.get("cross_season_precision_at_5"),
                             wider)  # fmt: skip
        console.print(check.text, highlight=False)
        probe = data.query[check.example]
        request = data_dir / "demo-localize.json"
        b64 = base64.b64encode(np.ascontiguousarray(probe, dtype="<f4").tobytes()).decode("ascii")
        request.write_text(json.dumps({"map": DEMO_MAP, "descriptor_b64": b64}))
        sample = np.ascontiguousarray(data.query[:100], dtype="<f4")
        np.save(data_dir / "demo-queries.npy", sample, allow_pickle=False)
        (data_dir / "demo-queries.f32").write_bytes(sample.tobytes())
        print_examples(console, server.url, token, grpc_port if _listening(grpc_port) else 0,
                       data_dir, check.example, probe, data.query_image(check.example),
                       server.log_path, check.example_index)  # fmt: skip
        while server.proc is not None and server.proc.poll() is None:
            time.sleep(0.5)
        raise UnavailableError(f"gridplace serve exited unexpectedly: {server.log()}")
    except KeyboardInterrupt:
        console.print("\nstopping the server…")
    finally:
        server.stop()


def _listening(port: int) -> bool:
    if not port:
        return False
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.settimeout(1.0)
        return s.connect_ex(("127.0.0.1", port)) == 0


@cli_errors
def demo(
    out: Annotated[Path | None, typer.Option(
        help="where the trained artifact is written (default: DATA_DIR/demo)",
        show_default=False)] = None,
    trainer: Annotated[str | None, typer.Option(
        help="logreg (the paper's) | svm | ridge | torch | prototype "
             f"(default: {default_trainer()})",
        show_default=False)] = None,
    patterns: Annotated[int | None, typer.Option(
        "--patterns", "-k", help="number of encoders k (default: the default configuration's)",
        show_default=False)] = None,
    rho: Annotated[float | None, typer.Option(
        help="fraction of columns per encoder (default: the default configuration's)",
        show_default=False)] = None,
    extractor: Annotated[str, typer.Option(
        help="descriptors of the Nordland frames: default (the service's default extractor, "
             "the CNN) | cnn | patchnorm")] = "default",
    frames: Annotated[
        int | None, typer.Option(help="use only the first N frames of the route")
    ] = None,
    synthetic: Annotated[
        bool, typer.Option("--synthetic", help="a SYNTHETIC route even if Nordland is present")
    ] = False,
    serve: Annotated[
        bool, typer.Option("--serve/--no-serve", help="then serve the model (Ctrl-C stops)")
    ] = True,
    data_dir: Annotated[Path, typer.Option(help="registry the server serves (map 'demo')")] = Path(
        "gridplace-data"
    ),
    port: Annotated[int, typer.Option(help="REST port (another free one if taken)")] = 8080,
    grpc_port: Annotated[int, typer.Option(help="gRPC port, 0 = off")] = 50051,
) -> None:
    """Train on the Nordland route (summer), save, reload, and localize winter queries; then
    serve the model as map 'demo' and print curl / grpcurl / gridplace client examples."""
    if frames is not None and frames < 2:
        raise InvalidParameterError(f"--frames must be at least 2, got {frames}")
    if extractor not in EXTRACTORS:
        raise InvalidParameterError(f"--extractor must be one of {', '.join(EXTRACTORS)}")
    given = {"trainer": trainer, "n_patterns": patterns, "rho": rho}
    params = ModelParams.parse(**{k: v for k, v in given.items() if v is not None})
    out = data_dir / "demo" if out is None else out
    path = check_new_artifact_dir(out / f"phase-{params.trainer}-{time.strftime('%Y%m%d-%H%M%S')}")
    console.print(demo_banner(params.encoder_preset), highlight=False)
    data = demo_data(frames, synthetic, extractor, console)
    console.print(
        f"[bold]dataset[/]: {data.label}; N={data.reference.shape[0]}, d={data.reference.shape[1]}"
    )
    model, train_s = _fit(params, data.reference)
    save_model(model, path, extra={"train_seconds": train_s, "dataset": data.label})
    model = load_model(path)  # answer from the verified artifact, as the server does
    results = evaluate_all(console, model, params.encoder_preset, data)
    console.print(
        f"trained preset {params.encoder_preset} ({params.trainer}) in {train_s:.1f}s "
        f"(periods {list(getattr(model, 'periods_', []))}); artifact: {path}", highlight=False,
    )
    console.print(reading(results, data.reference.shape[0]), highlight=False, soft_wrap=True)
    (path.parent / f"{path.name}.results.json").write_text(
        json.dumps({k: {kk: v for kk, v in r.items() if kk != "footprint"} for k, r in results.items()},
                   indent=2, default=lambda o: o.item() if isinstance(o, np.generic) else str(o))
    )  # fmt: skip
    if serve:
        cross = results["gridplace/cross-season as sent"]["precision_at"]  # as /localize answers
        same = results["gridplace/identical"]["precision_at"]
        metrics = {"dataset": data.label, "train_seconds": train_s,
                   "train_precision_at_0": same["0"], "train_precision_at_5": same["5"],
                   "cross_season_precision_at_0": cross["0"], "cross_season_precision_at_5": cross["5"]}  # fmt: skip
        _serve(data_dir, port, grpc_port, model, params, data, metrics)


def register(app: typer.Typer) -> None:
    app.command()(demo)
