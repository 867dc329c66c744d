"""Schemathesis against the service's OpenAPI document, in process, with API keys on.

Shared by the stateless and stateful fuzz tests and by ``benchmarks/fuzz.py``. The app
queues jobs on a Celery queue of its own on the test Redis that no worker consumes, so
submitted jobs stay queued and cost nothing; :func:`fuzzed_app` deletes the queue and the
data folder afterwards. Each API key holds a seeded dataset, so identifications and
studies are generated with ids that exist and reach the checks against the data.
"""

from __future__ import annotations

import collections
import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import urlsplit, urlunsplit

import redis
import schemathesis
from hypothesis import strategies as st
from schemathesis.checks import not_a_server_error
from schemathesis.core.failures import FailureGroup
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
API_KEYS = ("fuzz-key", "fuzz-neighbour")
# No 5xx, and every answer documented: status, content type, body and headers. Schema-valid
# requests the service refuses on their meaning (an unknown channel, a band beyond Nyquist)
# are not failures, so positive-data acceptance is not among them.
CHECKS = [not_a_server_error, status_code_conformance, content_type_conformance,
          response_schema_conformance, response_headers_conformance, negative_data_rejection]


def fuzz_redis_url() -> str:
    """The Redis of FNSI_REDIS_URL, database 14 (fuzzing queues only)."""
    parts = urlsplit(os.environ.get("FNSI_REDIS_URL", "redis://127.0.0.1:6379/0"))
    return urlunsplit(parts._replace(path=f"/{FUZZ_REDIS_DB}"))


@dataclass
class Fuzzed:
    """The app under test, its schema and one seeded dataset id per API key."""

    schema: schemathesis.BaseSchema
    settings: Settings
    datasets: dict[str, str] = field(default_factory=dict)


def seed_datasets(settings: Settings) -> dict[str, str]:
    """Store the test record once for each API key; returns key -> dataset id."""
    rec = formats.make_record()
    measurement = Measurement.from_arrays(rec.u, rec.y, rec.fs, input_names=rec.input_names,
                                          output_names=rec.output_names, periods=rec.periods)
    store = Store(settings.data_dir)
    return {key: store.put_measurement(measurement, owner=get_owner(settings, key),
                                       name="seeded").id for key in API_KEYS}


@contextmanager
def fuzzed_app(name: str) -> Iterator[Fuzzed]:
    """An app on a private queue and data folder, seeded; cleaned up on exit."""
    queue = f"fnsi-{name}-{os.getpid()}"
    settings = Settings(data_dir=Path(tempfile.gettempdir()) / queue,
                        broker_url=fuzz_redis_url(), queue_name=queue, api_keys=list(API_KEYS))
    app = create_app(settings)
    schema = schemathesis.openapi.from_dict(app.openapi())
    schema.app = app
    fuzzed = Fuzzed(schema, settings, seed_datasets(settings))

    @schema.hook
    def flatmap_body(context, body) -> st.SearchStrategy:
        """Half the bodies naming a dataset name a seeded one, so requests also get past
        the existence check into the checks against the data."""
        if isinstance(body, dict) and "dataset_id" in body:
            return st.sampled_from([body, {**body, "dataset_id": fuzzed.datasets[API_KEYS[0]]}])
        return st.just(body)

    try:
        yield fuzzed
    finally:
        shutdown_lifespans()
        broker = redis.Redis.from_url(fuzz_redis_url())
        for key in broker.scan_iter(f"*{queue}*"):
            broker.delete(key)
        shutil.rmtree(settings.data_dir, ignore_errors=True)


@dataclass
class Tally:
    """What a stateful run sent and got: requests, statuses and failed checks."""

    requests: int = 0
    server_errors: int = 0
    violations: int = 0
    statuses: collections.Counter = field(default_factory=collections.Counter)
    operations: collections.Counter = field(default_factory=collections.Counter)
    failures: list[str] = field(default_factory=list)


def state_machine(fuzzed: Fuzzed, tally: Tally, *, raise_failures: bool):
    """Schemathesis' state machine over the links it infers between operations (a created
    dataset, job or study is fetched, listed, revised, cancelled ...), sending the first
    API key, counting into ``tally``; failures raise or are only counted."""
    base = fuzzed.schema.as_state_machine()

    class Machine(base):
        def get_call_kwargs(self, case):
            return {"headers": {"X-API-Key": API_KEYS[0]}}

        def after_call(self, response, case):
            tally.requests += 1
            tally.statuses[response.status_code] += 1
            tally.operations[f"{case.method} {case.path}"] += 1
            tally.server_errors += response.status_code >= 500

        def validate_response(self, response, case, additional_checks=None, **kwargs):
            try:
                case.validate_response(response, checks=CHECKS, transport_kwargs=kwargs)
            except FailureGroup as failures:
                tally.violations += len(failures.exceptions)
                tally.failures.extend(f"{case.method} {case.path}: {f.title}"
                                      for f in failures.exceptions)
                if raise_failures:
                    raise

    return Machine
