"""Fixtures: an in-process app per test, and real servers (uvicorn, Celery, Redis)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from service.app import create_app
from service.settings import Settings
from tests.service.servers import Stack, start_stack
from tests.service.servers import celery_stack as running_celery_stack


@pytest.fixture
def make_client(tmp_path: Path, database) -> Iterator:
    """Factory of TestClients on fresh data dirs and databases (lifespan entered, embedded
    runner)."""
    clients = []

    def make(**overrides) -> TestClient:
        settings = Settings(data_dir=tmp_path / f"data{len(clients)}", broker_url=None,
                            database_url=database(), **overrides)
        client = TestClient(create_app(settings), raise_server_exceptions=False)
        client.__enter__()
        clients.append(client)
        return client

    yield make
    for client in clients:
        client.__exit__(None, None, None)


@pytest.fixture
def client(make_client) -> TestClient:
    """An app with default settings on a fresh data dir."""
    return make_client()


@pytest.fixture(scope="session")
def embedded_stack(tmp_path_factory) -> Iterator[Stack]:
    """fnsi-service alone: jobs on its embedded runner."""
    stack = start_stack(tmp_path_factory.mktemp("embedded") / "data")
    yield stack
    stack.stop()


@pytest.fixture(scope="session")
def celery_stack(tmp_path_factory) -> Iterator[Stack]:
    """fnsi-service with a Redis broker and one fnsi-worker process."""
    with running_celery_stack(tmp_path_factory.mktemp("celery") / "data") as stack:
        yield stack


@pytest.fixture(scope="session", params=["embedded", "celery"])
def stack(request) -> Stack:
    """Each end-to-end test runs on both execution modes."""
    return request.getfixturevalue(f"{request.param}_stack")
