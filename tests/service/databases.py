"""PostgreSQL for the tests: a database of their own per session, a schema per store.

The server is the one of FNSI_TEST_POSTGRES_URL (default: the local trust-auth server,
``postgresql://postgres@127.0.0.1:5432/test``); its database is only used to create and
drop ``pg_<random>``, which the session's stores share, each in a fresh schema (cheap,
and as empty as a new SQLite file). Without a server the PostgreSQL tests are skipped,
saying how to get one.
"""

from __future__ import annotations

import os
import secrets
from collections.abc import Iterator
from contextlib import contextmanager
from urllib.parse import quote, urlsplit, urlunsplit

import psycopg
import pytest

ADMIN_URL = os.environ.get("FNSI_TEST_POSTGRES_URL", "postgresql://postgres@127.0.0.1:5432/test")


def _with_database(url: str, database: str, query: str = "") -> str:
    return urlunsplit(urlsplit(url)._replace(path=f"/{database}", query=query))


def skip_without_postgres() -> None:
    """Skip the calling test, saying why and what to do, when no server answers."""
    try:
        psycopg.connect(ADMIN_URL, connect_timeout=3).close()
    except psycopg.OperationalError as err:
        pytest.skip(f"no PostgreSQL at {ADMIN_URL} ({str(err).strip()}): start one (README, "
                    "'Scaling out') or point FNSI_TEST_POSTGRES_URL at one")


@contextmanager
def temporary_database() -> Iterator[str]:
    """URL of a new database ``pg_<random>``, dropped (with its connections) afterwards."""
    name = f"pg_{secrets.token_hex(6)}"
    with psycopg.connect(ADMIN_URL, autocommit=True) as admin:
        admin.execute(f'CREATE DATABASE "{name}"')
    try:
        yield _with_database(ADMIN_URL, name)
    finally:
        with psycopg.connect(ADMIN_URL, autocommit=True) as admin:
            admin.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


def fresh_schema(database_url: str) -> str:
    """URL of a new, empty schema in ``database_url`` (its default for every table)."""
    schema = f"s_{secrets.token_hex(6)}"
    with psycopg.connect(database_url, autocommit=True) as db:
        db.execute(f'CREATE SCHEMA "{schema}"')
    options = quote(f"-csearch_path={schema}")
    return _with_database(database_url, urlsplit(database_url).path.lstrip("/"),
                          f"options={options}")
