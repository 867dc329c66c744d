"""Schemathesis against the OpenAPI document, in process: whatever a client sends, the API
answers without a 5xx, with a documented status, content type and response schema.

Jobs the fuzzer manages to submit go to a Celery queue of their own on the test Redis that
no worker consumes, so they stay queued and cost nothing; the queue is deleted afterwards.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from urllib.parse import urlsplit, urlunsplit

import pytest
import redis
import schemathesis
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from schemathesis.checks import not_a_server_error
from schemathesis.python.asgi import shutdown_lifespans
from schemathesis.specs.openapi.checks import (
    content_type_conformance,
    negative_data_rejection,
    response_headers_conformance,
    response_schema_conformance,
    status_code_conformance,
)

from fnsi.measurement import Measurement
from service.app import create_app
from service.deps import get_owner
from service.settings import Settings
from service.store import Store
from tests.service import formats

FUZZ_REDIS_DB = 14
# Examples per operation: 15 operations x 25 keep the run near half a minute on 2 cores.
MAX_EXAMPLES = 25
CHECKS = [not_a_server_error, status_code_conformance, content_type_conformance,
          response_schema_conformance, response_headers_conformance, negative_data_rejection]


def fuzz_redis_url() -> str:
    """The Redis of FNSI_REDIS_URL, database 14 (this module's queue only)."""
    parts = urlsplit(os.environ.get("FNSI_REDIS_URL", "redis://127.0.0.1:6379/0"))
    return urlunsplit(parts._replace(path=f"/{FUZZ_REDIS_DB}"))


API_KEY = "fuzz-key"
QUEUE = f"fnsi-fuzz-{os.getpid()}"
SETTINGS = Settings(data_dir=Path(tempfile.gettempdir()) / QUEUE, broker_url=fuzz_redis_url(),
                    queue_name=QUEUE, api_keys=[API_KEY])
# The document is read now (collection); the app's lifespan, which creates the store and
# connects the queue, starts with the first request of the test.
APP = create_app(SETTINGS)
schema = schemathesis.openapi.from_dict(APP.openapi())
schema.app = APP
SEEDED: dict[str, str] = {}


@schema.hook
def flatmap_body(context, body) -> st.SearchStrategy:
    """Half the bodies naming a dataset name the seeded one, so requests also get past the
    existence check into the checks against the data."""
    if isinstance(body, dict) and "dataset_id" in body and SEEDED:
        return st.sampled_from([body, {**body, "dataset_id": SEEDED["id"]}])
    return st.just(body)


@pytest.fixture(scope="module", autouse=True)
def _seeded_store() -> Iterator[None]:
    """A dataset of the fuzzing key to aim at; afterwards stop the app, delete its queue
    from Redis and its data dir."""
    rec = formats.make_record()
    measurement = Measurement.from_arrays(rec.u, rec.y, rec.fs, input_names=rec.input_names,
                                          output_names=rec.output_names, periods=rec.periods)
    owner = get_owner(SETTINGS, API_KEY)
    SEEDED["id"] = Store(SETTINGS.data_dir).put_measurement(measurement, owner=owner,
                                                            name="seeded").id
    yield
    SEEDED.clear()
    shutdown_lifespans()
    broker = redis.Redis.from_url(fuzz_redis_url())
    for key in broker.scan_iter(f"*{QUEUE}*"):
        broker.delete(key)
    shutil.rmtree(SETTINGS.data_dir, ignore_errors=True)


@schema.parametrize()
@settings(max_examples=MAX_EXAMPLES, deadline=None, database=None, derandomize=True,
          suppress_health_check=list(HealthCheck))
def test_api_answers_every_request_as_documented(case):
    case.call_and_validate(checks=CHECKS, headers={"X-API-Key": API_KEY})
