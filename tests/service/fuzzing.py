"""Schemathesis against the service's OpenAPI document, in process, with API keys on.

Shared by the stateless and stateful fuzz tests and by ``benchmarks/fuzz.py``. The app
queues jobs on a Celery queue of its own on the test Redis that no worker consumes, so
submitted jobs stay queued and cost nothing; :func:`fuzzed_app` deletes the queue and the
data folder afterwards. Each API key holds a seeded dataset, so identifications and
studies are generated with ids that exist and reach the checks against the data.

Each stateful sequence calls as a tenant of its own: what it creates is invisible to the
other sequences, so a sequence replayed by Hypothesis meets the state it met first.
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
    """The app under test, its schema, one seeded dataset id per API key and the key the
    requests are sent with."""

    schema: schemathesis.BaseSchema
    settings: Settings
    datasets: dict[str, str] = field(default_factory=dict)
    key: str = API_KEYS[0]

    def seed(self, key: str) -> None:
        """Store the test record for ``key`` (once) and send requests with that key."""
        if key not in self.datasets:
            rec = formats.make_record()
            measurement = Measurement.from_arrays(
                rec.u, rec.y, rec.fs, input_names=rec.input_names,
                output_names=rec.output_names, periods=rec.periods)
            owner = get_owner(self.settings, key)
            self.datasets[key] = Store(self.settings.data_dir).put_measurement(
                measurement, owner=owner, name="seeded").id
        self.key = key


@contextmanager
def fuzzed_app(name: str, tenants: int = 0) -> Iterator[Fuzzed]:
    """An app on a private queue and data folder with :data:`API_KEYS` and ``tenants``
    more keys (one per stateful sequence), seeded; cleaned up on exit."""
    queue = f"fnsi-{name}-{os.getpid()}"
    keys = [*API_KEYS, *(f"fuzz-tenant-{k}" for k in range(tenants))]
    settings = Settings(data_dir=Path(tempfile.gettempdir()) / queue,
                        broker_url=fuzz_redis_url(), queue_name=queue, api_keys=keys)
    app = create_app(settings)
    schema = schemathesis.openapi.from_dict(app.openapi())
    schema.app = app
    fuzzed = Fuzzed(schema, settings)
    for key in reversed(API_KEYS):
        fuzzed.seed(key)

    @schema.hook
    def flatmap_body(context, body) -> st.SearchStrategy:
        """Half the bodies naming a dataset name a seeded one, so requests also get past
        the existence check into the checks against the data."""
        if isinstance(body, dict) and "dataset_id" in body:
            return st.sampled_from([body, {**body, "dataset_id": fuzzed.datasets[fuzzed.key]}])
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
    followed: int = 0  # 2xx answers on a path naming an object (a link that led somewhere)
    statuses: collections.Counter = field(default_factory=collections.Counter)
    operations: collections.Counter = field(default_factory=collections.Counter)
    failures: list[str] = field(default_factory=list)


def state_machine(fuzzed: Fuzzed, tally: Tally):
    """Schemathesis' state machine over the links it infers between operations (a created
    dataset, job or study is fetched, listed, revised, cancelled ...), each sequence as a
    tenant of its own (the app needs ``tenants`` keys, one per sequence), counting
    requests and failed checks into ``tally``.

    Failures are counted, not raised: the app's store outlives each sequence, so
    Hypothesis could not replay a failing sequence to shrink it; the tally names it."""
    base = fuzzed.schema.as_state_machine()

    tenants = iter(fuzzed.settings.api_keys[len(API_KEYS):])

    class Machine(base):
        def setup(self):
            # More sequences than keys (Hypothesis may run a few extra) share the last.
            fuzzed.seed(next(tenants, fuzzed.key))

        def get_call_kwargs(self, case):
            return {"headers": {"X-API-Key": fuzzed.key}}

        def after_call(self, response, case):
            tally.requests += 1
            tally.statuses[response.status_code] += 1
            tally.operations[f"{case.method} {case.path}"] += 1
            tally.server_errors += response.status_code >= 500
            tally.followed += "{" in case.path and response.status_code < 300

        def validate_response(self, response, case, additional_checks=None, **kwargs):
            try:
                case.validate_response(response, checks=CHECKS, transport_kwargs=kwargs)
            except FailureGroup as failures:
                tally.violations += len(failures.exceptions)
                tally.failures.extend(f"{case.method} {case.path} -> {response.status_code}: "
                                      f"{f.title}" for f in failures.exceptions)

    return Machine
