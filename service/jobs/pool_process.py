"""What every process of the embedded training pool does first: tie its life to the server's.

The pool's workers are forked by multiprocessing's forkserver, so their parent is the
forkserver, not the server; and each worker holds the pipes that would tell the forkserver and
the others that the server is gone. Left alone, a ``kill -9`` of the server leaves the
forkserver, the resource tracker and the workers running (a worker in a fit trains on, then
blocks forever on its task queue). So each worker, before its first task:

* ignores SIGINT: Ctrl-C in a terminal goes to the whole process group, and the server (not
  each worker) decides what happens to a job: it marks the job failed and stops the pool;
* asks the kernel for SIGKILL when its parent (the single-threaded forkserver) dies
  (``PR_SET_PDEATHSIG``, Linux);
* watches the *server* with a daemon thread blocked on a pidfd (Linux ≥ 5.3; elsewhere it
  polls the pid every :data:`POLL_S`) and kills itself the moment the server exits.

When the last worker is gone, the forkserver sees its "alive" pipe close and exits, then the
resource tracker sees its pipe close and exits: nothing of the pool survives the server.
"""

from __future__ import annotations

import ctypes
import os
import select
import signal
import sys
import threading
import time

PR_SET_PDEATHSIG = 1
POLL_S = 1.0


def init_pool_process(server_pid: int, blas_threads: int) -> None:
    """The pool's ``initializer``: runs in each worker before its first task."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    parent = os.getppid()
    _die_with_parent()
    if os.getppid() != parent:  # the parent died before the request took effect
        _die()
    watch_server(server_pid)
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=blas_threads)  # the pool does not oversubscribe the cores


def _die() -> None:
    os.kill(os.getpid(), signal.SIGKILL)


def _die_with_parent() -> None:
    if not sys.platform.startswith("linux"):
        return
    libc = ctypes.CDLL(None, use_errno=True)
    libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)


def watch_server(pid: int) -> threading.Thread:
    """A daemon thread that kills this process as soon as process ``pid`` has exited."""
    fd: int | None = None
    try:
        fd = os.pidfd_open(pid)
    except ProcessLookupError:
        _die()  # the server is already gone
    except (AttributeError, OSError):
        pass  # no pidfd on this system: poll

    def watch() -> None:
        if fd is not None:
            select.select([fd], [], [])  # readable once the process has exited
        else:
            while pid_exists(pid):
                time.sleep(POLL_S)
        _die()

    thread = threading.Thread(target=watch, name="gridplace-server-watch", daemon=True)
    thread.start()
    return thread


def pid_exists(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
