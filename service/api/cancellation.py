"""Stop a request's work when its client goes away.

A drive's filter runs in a worker thread; :func:`run_until_disconnected` runs it there and
polls the connection while it does: when the client has gone, it sets the work's
:class:`~service.core.request_work.Cancellation`, which the filter reads between blocks of
frames, so an abandoned request stops costing CPU within one block (about 20 M units of
work). The answer to nobody is a 499 (:class:`~service.errors.CancelledError`), logged once.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from typing import TypeVar

from starlette.concurrency import run_in_threadpool
from starlette.requests import Request

from service.core.request_work import Cancellation
from service.errors import CancelledError

log = logging.getLogger("gridplace.api")
T = TypeVar("T")
POLL_S = 0.1  # how often the connection is looked at while the work runs


async def run_until_disconnected(request: Request, work: Callable[[Cancellation], T]) -> T:
    """``work(cancellation)`` in the thread pool, cancelled when the client disconnects."""
    cancellation = Cancellation()
    task = asyncio.ensure_future(run_in_threadpool(work, cancellation))
    try:
        while True:
            done, _ = await asyncio.wait({task}, timeout=POLL_S)
            if done:
                break
            if await request.is_disconnected():
                cancellation.cancel()
                break
        return await task
    except CancelledError as exc:
        log.info("%s %s: %s", request.method, request.url.path, exc.message)
        raise
    finally:
        if not task.done():  # the route itself was cancelled (server shutdown)
            cancellation.cancel()
