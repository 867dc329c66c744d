"""Stateful schemathesis run: thousands of requests along the links between operations.

The machine of ``tests/service/fuzzing.py`` (API keys on, a seeded dataset per key, jobs on
a queue no worker consumes) run for ``--sequences`` sequences of up to ``--steps`` calls;
failures are counted, not raised, so the run reports them all.

Last output line: one JSON object {"requests", "server_errors", "violations",
"followed_links", "statuses", "seconds"}. Run from the repository root:
``.venv/bin/python -m benchmarks.fuzz`` (needs the Redis at FNSI_REDIS_URL).
"""

from __future__ import annotations

import argparse
import json
import time

from hypothesis import HealthCheck, settings

from tests.service.fuzzing import Tally, fuzzed_app, state_machine


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sequences", type=int, default=250, help="call sequences (250)")
    parser.add_argument("--steps", type=int, default=12, help="most calls a sequence (12)")
    args = parser.parse_args()
    tally = Tally()
    start = time.perf_counter()
    with fuzzed_app("fuzz-bench", tenants=2 * args.sequences) as fuzzed:
        machine = state_machine(fuzzed, tally)
        machine.run(settings=settings(max_examples=args.sequences, stateful_step_count=args.steps,
                                      deadline=None, database=None,
                                      suppress_health_check=list(HealthCheck)))
    seconds = time.perf_counter() - start
    for operation, count in sorted(tally.operations.items()):
        print(f"{count:6d}  {operation}")
    for failure in sorted(set(tally.failures)):
        print(f"FAILED  {failure}")
    print(json.dumps({"requests": tally.requests, "server_errors": tally.server_errors,
                      "violations": tally.violations, "followed_links": tally.followed,
                      "statuses": {str(k): v for k, v in sorted(tally.statuses.items())},
                      "seconds": round(seconds, 1)}))


if __name__ == "__main__":
    main()
