"""The floor of a Python gRPC stream on this machine: a server that does no work.

``python -m service.bench.grpc_floor PORT`` serves ``gridplace.v1.Localization`` whose
``LocalizeStream`` answers every frame at once with a constant answer (no validation, no model,
no batching). Measured with the benchmark's own client, it is what transport alone costs, so a
target beyond it cannot be met by the service's code. Used by ``gridplace bench grpc --floor``.
"""

from __future__ import annotations

import asyncio
import subprocess
import sys
from collections.abc import AsyncIterator
from typing import Any

import grpc
import numpy as np

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


def measure_floor(qry: np.ndarray, period: int, frames: int, n_streams: int, window: int,
                  rounds: int = 3) -> dict[str, Any]:  # fmt: skip
    """The benchmark's stream measurement against the do-nothing server (rounds merged)."""
    from service.bench.grpc_bench import _merge, _throughput

    port = free_port()
    proc = subprocess.Popen([sys.executable, "-m", "service.bench.grpc_floor", str(port)],
                            stdout=subprocess.PIPE)  # fmt: skip
    try:
        assert proc.stdout is not None
        if proc.stdout.readline().strip() != b"ready":
            raise RuntimeError("the gRPC floor server did not start")
        per = max(n_streams, frames // rounds)
        parts = [_throughput(f"127.0.0.1:{port}", qry, period, per, n_streams, window, pid=proc.pid)
                 for _ in range(rounds)]  # fmt: skip
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    out = _merge(parts)
    out.pop("index")
    return out


if __name__ == "__main__":
    asyncio.run(_serve(int(sys.argv[1])))
