"""A uniquely named, throw-away PostgreSQL database (tests and benchmarks).

``with ScratchDatabase() as url: Registry(data_dir, url=url)`` creates ``gridplace_<random>``
on the server of ``admin_url`` (``GRIDPLACE_TEST_POSTGRES_URL``, default the local server as
user ``postgres``), and drops it — after closing every other connection to it — on exit.
Nothing else on that server is touched.
"""

from __future__ import annotations

import os
import uuid
from types import TracebackType

from sqlalchemy import create_engine, text
from sqlalchemy.exc import SQLAlchemyError
from sqlalchemy.pool import NullPool

from service.errors import UnavailableError
from service.registry.db import describe_url, parse_url

DEFAULT_ADMIN_URL = "postgresql://postgres@127.0.0.1:5432/postgres"


def admin_url() -> str:
    return os.environ.get("GRIDPLACE_TEST_POSTGRES_URL", DEFAULT_ADMIN_URL)


class ScratchDatabase:
    def __init__(self, admin: str | None = None, prefix: str = "gridplace") -> None:
        self._admin = parse_url(admin or admin_url())
        self.name = f"{prefix}_{uuid.uuid4().hex[:12]}"
        self.url = self._admin.set(database=self.name).render_as_string(hide_password=False)
        self._engine = create_engine(self._admin, poolclass=NullPool,
                                     isolation_level="AUTOCOMMIT",
                                     connect_args={"connect_timeout": 5})  # fmt: skip

    def create(self) -> str:
        try:
            with self._engine.connect() as conn:
                conn.execute(text(f'CREATE DATABASE "{self.name}"'))
        except SQLAlchemyError as exc:
            raise UnavailableError(
                f"cannot create a scratch database on {describe_url(self._admin)} "
                f"(PostgreSQL reachable? set GRIDPLACE_TEST_POSTGRES_URL): {exc}"
            ) from exc
        return self.url

    def drop(self) -> None:
        with self._engine.connect() as conn:
            conn.execute(text(f'DROP DATABASE IF EXISTS "{self.name}" WITH (FORCE)'))
        self._engine.dispose()

    def __enter__(self) -> str:
        return self.create()

    def __exit__(self, et: type[BaseException] | None, e: BaseException | None,
                 tb: TracebackType | None) -> None:  # fmt: skip
        self.drop()
