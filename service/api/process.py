"""Running ``gridplace serve`` as a child process (integration tests and ``bench serve``)."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from types import TracebackType

import httpx

from service.errors import UnavailableError


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class ServerProcess:
    """``with ServerProcess(data_dir, env={...}) as srv: httpx.get(srv.url + "/healthz")``."""

    def __init__(self, data_dir: Path, env: dict[str, str] | None = None, port: int | None = None,
                 log_path: Path | None = None, new_session: bool = False) -> None:  # fmt: skip
        """``new_session``: run in its own session and process group, as a shell job is, so
        :meth:`interrupt` can send Ctrl-C to the server and everything it started."""
        self.data_dir = data_dir
        self.new_session = new_session
        self.port = port or free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.env = {**os.environ, "GRIDPLACE_GRPC_PORT": "0", "GRIDPLACE_LOG_LEVEL": "warning",
                    **(env or {})}  # fmt: skip
        self.log_path = log_path or data_dir / f"server-{self.port}.log"
        self.proc: subprocess.Popen[bytes] | None = None
        self._log_start = 0  # where the latest start's output begins in the (appended) log

    def start(self, timeout_s: float = 60.0) -> ServerProcess:
        cmd = [sys.executable, "-m", "service.cli", "serve", "--host", "127.0.0.1",
               "--port", str(self.port), "--data-dir", str(self.data_dir)]  # fmt: skip
        self.data_dir.mkdir(parents=True, exist_ok=True)
        self._log_start = self.log_path.stat().st_size if self.log_path.exists() else 0
        log = open(self.log_path, "ab")  # noqa: SIM115 - owned by the child
        self.proc = subprocess.Popen(cmd, env=self.env, stdout=log, stderr=subprocess.STDOUT,
                                     start_new_session=self.new_session)  # fmt: skip
        log.close()
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise UnavailableError(f"gridplace serve exited with {self.proc.returncode}: {self.log()}")
            try:
                if httpx.get(self.url + "/healthz", timeout=1.0).status_code == 200:
                    return self
            except httpx.TransportError:
                pass
            time.sleep(0.1)
        self.stop()
        raise UnavailableError(f"gridplace serve did not answer within {timeout_s}s: {self.log()}")

    def wait_ready(self, timeout_s: float = 60.0) -> None:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if httpx.get(self.url + "/readyz", timeout=5.0).status_code == 200:
                return
            time.sleep(0.1)
        raise UnavailableError(f"gridplace serve not ready within {timeout_s}s: {self.log()}")

    def stop(self, timeout_s: float = 20.0) -> int | None:
        if self.proc is None:
            return None
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        code = self.proc.returncode
        self.proc = None
        return code

    def interrupt(self, sig: int = signal.SIGINT) -> None:
        """Send ``sig`` to the server's whole process group, as Ctrl-C in a terminal does
        (only with ``new_session``; otherwise to the server alone)."""
        if self.proc is None or self.proc.poll() is not None:
            return
        if self.new_session:
            os.killpg(self.proc.pid, sig)
        else:
            self.proc.send_signal(sig)

    def log(self) -> str:
        """The latest start's output (a restarted server appends to the same file; what an
        earlier, killed run's processes printed is not this run's)."""
        try:
            with self.log_path.open("rb") as f:
                f.seek(self._log_start)
                return f.read().decode(errors="replace")[-4000:]
        except OSError:
            return ""

    def __enter__(self) -> ServerProcess:
        return self.start()

    def __exit__(self, et: type[BaseException] | None, e: BaseException | None,
                 tb: TracebackType | None) -> None:  # fmt: skip
        self.stop()
