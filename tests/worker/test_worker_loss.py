"""A worker killed with SIGKILL mid-job: the job is re-run or failed, never left running."""

from __future__ import annotations

import os
import signal
from pathlib import Path

from tests.service.servers import wait_for_job, wait_for_progress
from tests.service.test_simulations import REQUEST as MODEL_SIMULATION

# ~10 s of Newmark integration (200 periods at 20 kHz), reporting progress every period.
LONG = {**MODEL_SIMULATION, "periods": 200, "fs_int": 20000.0}


def start_long_job(client) -> str:
    job_id = client.post("/v1/simulations", json=LONG).json()["id"]
    wait_for_progress(client, job_id, 0.1)
    return job_id


def pool_children(pid: int) -> list[int]:
    return [int(c) for c in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]


def test_killed_worker_process_group_job_reruns_on_another_worker(celery_stack):
    with celery_stack.client() as client:
        job_id = start_long_job(client)
        celery_stack.kill_worker(celery_stack.workers[0])
        celery_stack.start_worker("replacement")
        final = wait_for_job(client, job_id, timeout=120)
        assert final["state"] == "succeeded", final
        assert final["attempts"] == 2
        dataset = client.get(f"/v1/datasets/{final['result']['dataset_id']}").json()
        assert dataset["periods"] == LONG["periods"]


def test_killed_pool_process_job_reruns_on_the_same_worker(celery_stack):
    with celery_stack.client() as client:
        job_id = start_long_job(client)
        (child,) = pool_children(celery_stack.workers[0].pid)
        os.kill(child, signal.SIGKILL)
        final = wait_for_job(client, job_id, timeout=120)
        assert final["state"] == "succeeded", final
        assert final["attempts"] == 2


def test_a_job_requeued_after_its_worker_died_runs_before_those_waiting(celery_stack):
    """One worker: A runs, B and C wait; the worker dies, A is re-queued (its lease
    lapsed) behind B and C, and the restarted worker still runs A first."""
    with celery_stack.client() as client:
        first = start_long_job(client)
        waiting = [client.post("/v1/simulations", json={**MODEL_SIMULATION, "seed": s}).json()
                   ["id"] for s in (11, 12)]
        celery_stack.kill_worker(celery_stack.workers[0])
        requeued = wait_for_job(client, first, timeout=60, states=("queued",))
        assert requeued["attempts"] == 1, requeued
        celery_stack.start_worker("restarted")
        finals = [wait_for_job(client, job_id, timeout=180) for job_id in (first, *waiting)]
    assert [f["state"] for f in finals] == ["succeeded"] * 3, finals
    assert finals[0]["attempts"] == 2
    assert finals[0]["started_at"] < min(f["started_at"] for f in finals[1:]), finals
