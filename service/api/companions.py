"""The hook through which other transports run in the REST server's process.

A *companion* is started after the model store and stopped before it, and is handed the
same :class:`~service.core.context.ServiceContext` (model store + service layer) as REST.
The gRPC server plugs in this way: ``service/grpc/server.py`` provides::

    def make_companion(settings: Settings) -> Companion | None: ...

(``None`` when ``settings.grpc_port == 0``). Nothing else has to change in ``serve``.
"""

from __future__ import annotations

import importlib
import logging
from typing import Protocol

from service.core.context import ServiceContext
from service.settings import Settings

log = logging.getLogger("gridplace.companions")

COMPANION_MODULES = ("service.grpc.server",)


class Companion(Protocol):
    name: str

    def start(self, context: ServiceContext) -> None: ...

    def stop(self) -> None: ...


def discover_companions(settings: Settings) -> list[Companion]:
    """Companions of the installed transports (none until ``service.grpc`` exists)."""
    found: list[Companion] = []
    for module_name in COMPANION_MODULES:
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name and module_name.startswith(exc.name):
                continue  # the transport is not part of this build
            raise
        factory = getattr(module, "make_companion", None)
        if factory is None:
            continue
        companion = factory(settings)
        if companion is not None:
            log.info("starting companion %s", companion.name)
            found.append(companion)
    return found
