"""Helpers for the registry tests on PostgreSQL."""

from __future__ import annotations

from sqlalchemy import create_engine, text
from sqlalchemy.pool import NullPool

from service.registry.db import parse_url

TABLES = ("versions", "maps", "jobs", "version_counters")


def empty_database(url: str) -> None:
    """Delete every row a previous test left (the schema stays)."""
    engine = create_engine(parse_url(url), poolclass=NullPool)
    with engine.begin() as conn:
        if conn.execute(text("SELECT to_regclass('public.meta')")).scalar() is not None:
            for table in TABLES:
                conn.execute(text(f"DELETE FROM {table}"))
            conn.execute(text("UPDATE meta SET value = 0 WHERE key = 'generation'"))
    engine.dispose()
