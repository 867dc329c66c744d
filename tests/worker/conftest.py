"""A Celery stack of its own: these tests kill workers."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from tests.service.servers import Stack
from tests.service.servers import celery_stack as running_celery_stack


@pytest.fixture(scope="module")
def celery_stack(tmp_path_factory) -> Iterator[Stack]:
    with running_celery_stack(tmp_path_factory.mktemp("kill") / "data") as stack:
        yield stack
