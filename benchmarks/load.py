"""Load on the HTTP API: status polls while jobs compute, and job throughput.

Two scenarios, each against real processes on this machine:

* ``polls`` (default): fnsi-service with ``--workers`` job processes, on its embedded
  runner (``--stack embedded``) or on fnsi-worker processes (``--stack celery``), runs
  as many long simulations as it has workers; while they compute, ``--clients``
  concurrent clients each get a running job's status (``GET /v1/jobs/{id}``) and list
  their jobs (``GET /v1/jobs``), pausing ``--poll`` seconds between requests, for
  ``--seconds``. The target: p99 < 50 ms. ``--job-nice 0`` runs the jobs at the API's
  priority (FNSI_JOB_NICE=0), for comparison.
* ``throughput``: simulates one small dataset (2-DOF chain with a cubic spring, 3 periods
  x 1000 samples), warms each worker with one job, then the clients submit ``--jobs``
  identifications between them and poll each job's status every ``--poll`` seconds until
  all are terminal; reports jobs per minute, poll and submission latency.

Celery stacks use the Redis at FNSI_REDIS_URL (default redis://127.0.0.1:6379, database
13, flushed afterwards). ``--database postgresql`` keeps records, blobs and artefacts in a
PostgreSQL database made for the run on the server of FNSI_TEST_POSTGRES_URL (default
postgresql://postgres@127.0.0.1:5432/test) and dropped afterwards; the default is SQLite
in the data folder. The last output line is one JSON object with the figures
(``poll_p50_ms``, ``poll_p99_ms``, the load average of the machine, ...).

Run from the repository root (it reuses the test suite's server helpers):
``.venv/bin/python -m benchmarks.load`` (about a minute; ``--scenario throughput``: a few
minutes on 2 cores).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import tempfile
import time
from contextlib import nullcontext
from pathlib import Path
from urllib.parse import urlsplit, urlunsplit

import httpx
import numpy as np
import redis

from tests.service.databases import temporary_database
from tests.service.servers import Stack, service_env, wait_for_job, wait_for_progress
from tests.service.test_simulations import REQUEST as MODEL_SIMULATION

LOAD_REDIS_DB = 13
TERMINAL = ("succeeded", "failed", "cancelled")
# Linear identification at a fixed order of the simulated 2-DOF chain: the smallest
# request that still runs every stage (spectra, decomposition, model, modes, errors, plots).
IDENTIFICATION = {"band": [5.0, 40.0], "block_rows": 4, "order": 4, "max_order": 4}
# 2e8 Newmark steps (1000 periods of 5000 samples at 40x): minutes of work on an idle
# core, so both jobs compute through the whole polling window; progress every period.
LONG_SIMULATION = {**MODEL_SIMULATION, "periods": 1000, "fs_int": 20000.0,
                   "excitation": {**MODEL_SIMULATION["excitation"],
                                  "samples_per_period": 5000}}


def redis_url() -> str:
    parts = urlsplit(os.environ.get("FNSI_REDIS_URL", "redis://127.0.0.1:6379/0"))
    return urlunsplit(parts._replace(path=f"/{LOAD_REDIS_DB}"))


def start(data_dir: Path, stack_kind: str, workers: int, job_nice: int,
          database_url: str | None = None) -> Stack:
    """API and job processes with production lease and supervisor periods (not the tests');
    with ``database_url``, records and blobs in that PostgreSQL database."""
    data_dir.mkdir(parents=True)
    broker = {"FNSI_BROKER_URL": redis_url()} if stack_kind == "celery" else {}
    shared = ({"FNSI_DATABASE_URL": database_url, "FNSI_BLOB_STORE": "database"}
              if database_url else {})
    env = service_env(data_dir, **broker, **shared)
    env.update(FNSI_LEASE_SECONDS="30", FNSI_SUPERVISOR_INTERVAL="5",
               FNSI_QUEUE_NAME=f"fnsi-load-{os.getpid()}", FNSI_JOB_NICE=str(job_nice),
               FNSI_EMBEDDED_WORKERS=str(workers))
    stack = Stack("", data_dir, env, None)
    stack.start_api()
    if stack_kind == "celery":
        for k in range(workers):
            stack.start_worker(f"load{k}")
    return stack


def percentiles(latencies: list[float], what: str = "poll") -> dict[str, float]:
    """p50 and p99 [ms] of latencies [s]."""
    return {f"{what}_p50_ms": round(1e3 * float(np.median(latencies)), 1),
            f"{what}_p99_ms": round(1e3 * float(np.percentile(latencies, 99)), 1)}


async def poller(url: str, job_ids: list[str], k: int, poll: float, until: float,
                 polls: list[float]) -> None:
    """One client: alternately a running job's status and the job listing, ``poll`` s
    apart, until ``until`` (monotonic clock)."""
    async with httpx.AsyncClient(base_url=url, timeout=60) as client:
        await asyncio.sleep(poll * k / 20)  # the clients' requests spread over the pause
        while time.monotonic() < until:
            for path in (f"/v1/jobs/{job_ids[k % len(job_ids)]}", "/v1/jobs"):
                t = time.perf_counter()
                (await client.get(path)).raise_for_status()
                polls.append(time.perf_counter() - t)
                await asyncio.sleep(poll)


async def pollers(url: str, job_ids: list[str], clients: int, poll: float, until: float,
                  polls: list[float]) -> None:
    """``clients`` concurrent pollers."""
    await asyncio.gather(*(poller(url, job_ids, k, poll, until, polls) for k in range(clients)))


def polls_while_computing(stack: Stack, workers: int, clients: int, poll: float,
                          seconds: float) -> dict:
    """The ``polls`` scenario: status polls and listings while ``workers`` jobs compute."""
    with stack.client() as client:
        job_ids = [client.post("/v1/simulations", json=LONG_SIMULATION).json()["id"]
                   for _ in range(workers)]
        for job_id in job_ids:
            wait_for_progress(client, job_id, 0.01, timeout=120)
    polls: list[float] = []
    load_before = os.getloadavg()
    until = time.monotonic() + seconds
    asyncio.run(pollers(stack.url, job_ids, clients, poll, until, polls))
    load_after = os.getloadavg()
    with stack.client() as client:
        states = [client.get(f"/v1/jobs/{j}").json()["state"] for j in job_ids]
    print(f"{len(polls)} requests in {seconds:g} s; jobs at the end: {states}; load average "
          f"(1 min) {load_before[0]:.2f} before, {load_after[0]:.2f} after")
    if states.count("running") < workers:
        print("WARNING: a job finished inside the window, so part of it was measured "
              "without load; lengthen LONG_SIMULATION")
    return {"requests": len(polls), "jobs_still_running": states.count("running"),
            "load_1min_before": round(load_before[0], 2),
            "load_1min_after": round(load_after[0], 2), **percentiles(polls)}


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
            **percentiles(polls), **percentiles(submits, "submit")}


def throughput(stack: Stack, workers: int, jobs: int, clients: int, poll: float) -> dict:
    """The ``throughput`` scenario: ``jobs`` small identifications from the clients."""
    with stack.client() as client:
        submitted = client.post("/v1/simulations", json=MODEL_SIMULATION).json()
        dataset_id = wait_for_job(client, submitted["id"])["result"]["dataset_id"]
        # one job per worker first: the first job of a process pays its imports
        warm = [client.post("/v1/identifications", json={
            "dataset_id": dataset_id, **IDENTIFICATION}).json()["id"] for _ in range(workers)]
        for job_id in warm:
            wait_for_job(client, job_id)
    return asyncio.run(load(stack.url, dataset_id, jobs, clients, poll))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scenario", choices=("polls", "throughput"), default="polls")
    parser.add_argument("--stack", choices=("embedded", "celery"), default="embedded",
                        help="embedded runner, or fnsi-worker processes on Redis")
    parser.add_argument("--database", choices=("sqlite", "postgresql"), default="sqlite",
                        help="records (and, with postgresql, blobs) in SQLite in the data "
                        "folder, or in a PostgreSQL database made for the run")
    parser.add_argument("--workers", type=int, default=2, help="job processes")
    parser.add_argument("--clients", type=int, default=20)
    parser.add_argument("--poll", type=float, default=0.5, help="seconds between requests")
    parser.add_argument("--seconds", type=float, default=30.0,
                        help="polls scenario: how long the clients poll")
    parser.add_argument("--jobs", type=int, default=200, help="throughput scenario: jobs")
    parser.add_argument("--job-nice", type=int, default=10,
                        help="FNSI_JOB_NICE of the job processes (0: the API's priority)")
    args = parser.parse_args()
    print(f"{args.scenario} on {args.stack}, {args.database}: {args.clients} clients, "
          f"{args.workers} job "
          f"processes at nice {args.job_nice}, requests every {args.poll} s; load average "
          f"(1 min) {os.getloadavg()[0]:.2f}")
    database = temporary_database() if args.database == "postgresql" else nullcontext()
    with tempfile.TemporaryDirectory(prefix="fnsi-load-") as folder, database as url:
        stack = start(Path(folder) / "data", args.stack, args.workers, args.job_nice, url)
        try:
            if args.scenario == "polls":
                summary = polls_while_computing(stack, args.workers, args.clients, args.poll,
                                                args.seconds)
            else:
                summary = throughput(stack, args.workers, args.jobs, args.clients, args.poll)
        finally:
            stack.stop()
            if args.stack == "celery":
                redis.Redis.from_url(redis_url()).flushdb()  # the benchmark's own database
    print(json.dumps({"scenario": args.scenario, "stack": args.stack,
                      "database": args.database, "job_nice": args.job_nice, **summary}))


if __name__ == "__main__":
    main()
