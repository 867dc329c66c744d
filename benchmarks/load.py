"""Load on the HTTP API: many small identifications from concurrent clients.

Starts fnsi-service (uvicorn) and ``--workers`` fnsi-worker processes on the Redis at
FNSI_REDIS_URL (default redis://127.0.0.1:6379, database 13, flushed afterwards), simulates
one small dataset (2-DOF chain with a cubic spring, 3 periods x 1000 samples), warms
each worker with one job, then ``--clients`` concurrent clients submit ``--jobs``
identifications between them and poll each job's status every ``--poll`` seconds until
all are terminal.

Reports the throughput (jobs per minute from the first submission to the last job
finished), the latency of the status polls (p50, p99: the target is p99 < 50 ms while the
workers are busy), submission latency, and how many jobs finished and failed.

Last output line: one JSON object {"jobs", "finished", "failed",
"throughput_jobs_per_min", "poll_p50_ms", "poll_p99_ms"}.

Run from the repository root (it reuses the test suite's server helpers):
``.venv/bin/python -m benchmarks.load`` (a few minutes on 2 cores).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import tempfile
import time
from pathlib import Path
from urllib.parse import urlsplit, urlunsplit

import httpx
import numpy as np
import redis

from tests.service.servers import Stack, service_env, wait_for_job
from tests.service.test_simulations import REQUEST as MODEL_SIMULATION

LOAD_REDIS_DB = 13
TERMINAL = ("succeeded", "failed", "cancelled")
# Linear identification at a fixed order of the simulated 2-DOF chain: the smallest
# request that still runs every stage (spectra, decomposition, model, modes, errors, plots).
IDENTIFICATION = {"band": [5.0, 40.0], "block_rows": 4, "order": 4, "max_order": 4}


def redis_url() -> str:
    parts = urlsplit(os.environ.get("FNSI_REDIS_URL", "redis://127.0.0.1:6379/0"))
    return urlunsplit(parts._replace(path=f"/{LOAD_REDIS_DB}"))


def start(data_dir: Path, workers: int) -> Stack:
    """API and workers with production lease and supervisor periods (not the tests')."""
    data_dir.mkdir(parents=True)
    env = service_env(data_dir, FNSI_BROKER_URL=redis_url())
    env.update(FNSI_LEASE_SECONDS="30", FNSI_SUPERVISOR_INTERVAL="5",
               FNSI_QUEUE_NAME=f"fnsi-load-{os.getpid()}")
    stack = Stack("", data_dir, env, None)
    stack.start_api()
    for k in range(workers):
        stack.start_worker(f"load{k}")
    return stack


async def client_run(url: str, dataset_id: str, jobs: int, poll: float,
                     polls: list[float], submits: list[float]) -> list[dict]:
    """One client: submit its jobs, then poll them all until each is terminal."""
    async with httpx.AsyncClient(base_url=url, timeout=60) as client:
        pending = []
        for _ in range(jobs):
            t = time.perf_counter()
            response = await client.post("/v1/identifications",
                                         json={"dataset_id": dataset_id, **IDENTIFICATION})
            submits.append(time.perf_counter() - t)
            response.raise_for_status()
            pending.append(response.json()["id"])
        finished = []
        while pending:
            await asyncio.sleep(poll)
            for job_id in list(pending):
                t = time.perf_counter()
                job = (await client.get(f"/v1/jobs/{job_id}")).json()
                polls.append(time.perf_counter() - t)
                if job["state"] in TERMINAL:
                    pending.remove(job_id)
                    finished.append(job)
        return finished


async def load(url: str, dataset_id: str, jobs: int, clients: int, poll: float) -> dict:
    polls: list[float] = []
    submits: list[float] = []
    shares = [jobs // clients + (k < jobs % clients) for k in range(clients)]
    start_time = time.perf_counter()
    results = await asyncio.gather(*(client_run(url, dataset_id, n, poll, polls, submits)
                                     for n in shares))
    finals = [job for result in results for job in result]
    last = max(job["finished_at"] for job in finals)
    first = min(job["created_at"] for job in finals)
    span = (np.datetime64(last[:23]) - np.datetime64(first[:23])) / np.timedelta64(1, "s")
    run = [(np.datetime64(j["finished_at"][:23]) - np.datetime64(j["started_at"][:23]))
           / np.timedelta64(1, "s") for j in finals if j["started_at"]]
    print(f"wall {time.perf_counter() - start_time:.1f} s; job run time p50 "
          f"{np.median(run):.2f} s, max {np.max(run):.2f} s; {len(polls)} polls; submit "
          f"p50 {1e3 * np.median(submits):.1f} ms, p99 {1e3 * np.percentile(submits, 99):.1f} ms")
    errors = {j["error"] for j in finals if j["state"] == "failed"}
    if errors:
        print(f"failures: {sorted(errors)[:3]}")
    return {"jobs": jobs, "finished": sum(j["state"] in TERMINAL for j in finals),
            "failed": sum(j["state"] == "failed" for j in finals),
            "throughput_jobs_per_min": round(60 * len(finals) / span, 1),
            "poll_p50_ms": round(1e3 * float(np.median(polls)), 1),
            "poll_p99_ms": round(1e3 * float(np.percentile(polls, 99)), 1)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--jobs", type=int, default=200)
    parser.add_argument("--clients", type=int, default=20)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--poll", type=float, default=0.5, help="seconds between poll rounds")
    parser.add_argument("--worker-nice", type=int, default=0,
                        help="niceness of the worker processes (0: same priority as the API)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="fnsi-load-") as folder:
        stack = start(Path(folder) / "data", args.workers)
        try:
            with stack.client() as client:
                submitted = client.post("/v1/simulations", json=MODEL_SIMULATION).json()
                dataset_id = wait_for_job(client, submitted["id"])["result"]["dataset_id"]
                # one job per worker first: the first job of a process pays its imports
                warm = [client.post("/v1/identifications", json={
                    "dataset_id": dataset_id, **IDENTIFICATION}).json()["id"]
                    for _ in range(args.workers)]
                for job_id in warm:
                    wait_for_job(client, job_id)
            for worker in stack.workers:  # the pool processes exist by now
                os.setpriority(os.PRIO_PGRP, worker.pid, args.worker_nice)
            print(f"{args.jobs} jobs, {args.clients} clients, {args.workers} workers at nice "
                  f"{args.worker_nice}, polls every {args.poll} s")
            summary = asyncio.run(load(stack.url, dataset_id, args.jobs, args.clients,
                                       args.poll))
        finally:
            stack.stop()
            redis.Redis.from_url(redis_url()).flushdb()  # the benchmark's own database
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
