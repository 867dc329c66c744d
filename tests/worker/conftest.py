"""A Celery stack of its own: these tests kill workers."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
import redis

from tests.service.servers import Stack, redis_test_url, start_stack


@pytest.fixture(scope="module")
def celery_stack(tmp_path_factory) -> Iterator[Stack]:
    url = redis_test_url()
    broker = redis.Redis.from_url(url)
    broker.flushdb()
    stack = start_stack(tmp_path_factory.mktemp("kill") / "data", broker_url=url, workers=1)
    yield stack
    stack.stop()
    broker.flushdb()
