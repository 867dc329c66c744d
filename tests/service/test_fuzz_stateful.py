"""Stateful schemathesis: sequences of calls that follow the links between operations (an
uploaded dataset is identified, a job fetched and cancelled, a study revised), with API
keys on and a seeded dataset per key. No 5xx and no answer outside the document.

``benchmarks/fuzz.py`` runs the same machine for thousands of requests and reports them.
"""

from __future__ import annotations

from hypothesis import HealthCheck, settings

from tests.service.fuzzing import Tally, fuzzed_app, state_machine

# 40 sequences of up to 10 calls: a few hundred requests, about a minute on 2 cores.
SEQUENCES, STEPS = 40, 10


def test_call_sequences_get_documented_answers_and_no_server_error():
    tally = Tally()
    with fuzzed_app("stateful", tenants=2 * SEQUENCES) as fuzzed:
        machine = state_machine(fuzzed, tally)
        machine.run(settings=settings(max_examples=SEQUENCES, stateful_step_count=STEPS,
                                      deadline=None, database=None, derandomize=True,
                                      suppress_health_check=list(HealthCheck)))
    assert tally.requests >= 200, tally
    assert tally.server_errors == 0 and tally.violations == 0, sorted(set(tally.failures))
    # the links were followed: objects created in a sequence were fetched, revised or
    # cancelled by id (random ids alone give only 404s)
    assert tally.followed >= 10, tally
