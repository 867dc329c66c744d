"""Schemathesis against the OpenAPI document, in process: whatever a client sends, the API
answers without a 5xx, with a documented status, content type and response schema.

The app, its private queue and the seeded datasets are set up by ``tests.service.fuzzing``.
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from hypothesis import HealthCheck, settings

from tests.service.fuzzing import API_KEYS, CHECKS, fuzzed_app

# Examples per operation: 15 operations x 25 keep the run near half a minute on 2 cores.
MAX_EXAMPLES = 25
# The document is read now (collection); the app's lifespan, which creates the store and
# connects the queue, starts with the first request of the test.
FUZZED = fuzzed_app("fuzz")
schema = FUZZED.__enter__().schema


@pytest.fixture(scope="module", autouse=True)
def _cleanup() -> Iterator[None]:
    """Stop the app, delete its queue from Redis and its data dir afterwards."""
    yield
    FUZZED.__exit__(None, None, None)


@schema.parametrize()
@settings(max_examples=MAX_EXAMPLES, deadline=None, database=None, derandomize=True,
          suppress_health_check=list(HealthCheck))
def test_api_answers_every_request_as_documented(case):
    case.call_and_validate(checks=CHECKS, headers={"X-API-Key": API_KEYS[0]})
