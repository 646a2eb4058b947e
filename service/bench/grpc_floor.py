"""The floor of a Python gRPC stream on this machine: a server that does no work.

``python -m service.bench.grpc_floor PORT`` serves ``gridplace.v1.Localization`` whose
``LocalizeStream`` answers every frame at once with a constant answer (no validation, no model,
no batching). Measured with the benchmark's own client, it is what transport alone costs, so a
target beyond it cannot be met by the service's code. Used by ``gridplace bench grpc --floor``,
which measures it in the same rounds as gridplace and gives gridplace's server CPU per frame
against it (:func:`fleet_efficiency`; target ``FLEET_TARGET``).
"""

from __future__ import annotations

import asyncio
import subprocess
import sys
from collections.abc import AsyncIterator
from typing import Any

import grpc

from service.api.process import free_port
from service.grpc.gen import localization_pb2 as pb
from service.grpc.gen import localization_pb2_grpc as pb_grpc


class _Floor(pb_grpc.LocalizationServicer):
    async def LocalizeStream(self, request_iterator: AsyncIterator[pb.StreamRequest],
                             context: grpc.aio.ServicerContext) -> AsyncIterator[pb.StreamResponse]:  # fmt: skip
        async for r in request_iterator:
            yield pb.StreamResponse(vehicle_id=r.vehicle_id, sequence=r.sequence, map=r.map,
                                    version=1, index=0, chunk=0, confidence=1.0, raw_index=0,
                                    raw_confidence=1.0, frames_used=1, latency_ms=0.0)  # fmt: skip


async def _serve(port: int) -> None:
    server = grpc.aio.server(options=[("grpc.max_receive_message_length", 64 * 1024 * 1024)])
    pb_grpc.add_LocalizationServicer_to_server(_Floor(), server)
    server.add_insecure_port(f"127.0.0.1:{port}")
    await server.start()
    print("ready", flush=True)
    await server.wait_for_termination()


class FloorServer:
    """``with FloorServer() as (target, pid):`` the do-nothing server in a child process."""

    def __enter__(self) -> tuple[str, int]:
        self.port = free_port()
        self.proc = subprocess.Popen([sys.executable, "-m", "service.bench.grpc_floor", str(self.port)],
                                     stdout=subprocess.PIPE)  # fmt: skip
        assert self.proc.stdout is not None
        if self.proc.stdout.readline().strip() != b"ready":
            self.__exit__()
            raise RuntimeError("the gRPC floor server did not start")
        return f"127.0.0.1:{self.port}", self.proc.pid

    def __exit__(self, *exc: object) -> None:
        self.proc.terminate()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


FLEET_TARGET = 1.3  # server CPU per frame, 8 adapted streams, against the floor's


def fleet_efficiency(streams: dict[str, Any], floor: dict[str, Any],
                     compute: dict[str, Any] | None = None) -> dict[str, Any]:  # fmt: skip
    """gridplace's server CPU per stream frame against the do-nothing server's, same run; with
    ``compute`` (:func:`service.bench.fleet_bound.compute_per_frame` of the same map and
    fleet), the least ratio any server on this transport could reach with that work."""
    from service.bench.fleet_bound import lower_bound_ratio  # not in the floor server's process

    ours, base = streams["server_cpu_us_per_frame"], floor["server_cpu_us_per_frame"]
    out = {"server_cpu_us_per_frame": ours, "floor_server_cpu_us_per_frame": base,
           "ratio": ours / base, "target_ratio": FLEET_TARGET,
           "adapted_fraction": streams.get("adapted_fraction"),
           "frames_per_s": streams["frames_per_s"], "floor_frames_per_s": floor["frames_per_s"]}  # fmt: skip
    if compute is not None:
        out["compute"] = compute
        out["lower_bound_ratio"] = lower_bound_ratio(compute["compute_us_per_frame"], base)
    return out


if __name__ == "__main__":
    asyncio.run(_serve(int(sys.argv[1])))
