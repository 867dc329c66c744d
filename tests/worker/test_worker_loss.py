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

