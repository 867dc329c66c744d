"""A job re-queued after its worker died runs before the jobs that were waiting."""

from __future__ import annotations

from tests.redis_server import LocalRedis
from tests.service.servers import start_stack, wait_for_job
from tests.service.test_simulations import REQUEST as MODEL_SIMULATION
from tests.worker.test_worker_loss import start_long_job


def test_a_job_requeued_after_its_worker_died_runs_before_those_waiting(tmp_path):
    """One worker: A runs, B and C wait; the worker dies, A is re-queued (its lease
    lapsed) behind B and C, and the restarted worker still runs A first. On a private
    redis-server: B and C wait in Redis for a minute, and other test runs flush the shared
    test database."""
    broker = LocalRedis.start()
    stack = start_stack(tmp_path / "data", broker_url=broker.url, workers=1)
    try:
        with stack.client() as client:
            first = start_long_job(client)
            waiting = [client.post("/v1/simulations", json={**MODEL_SIMULATION, "seed": s})
                       .json()["id"] for s in (11, 12)]
            stack.kill_worker(stack.workers[0])
            requeued = wait_for_job(client, first, timeout=60, states=("queued",))
            assert requeued["attempts"] == 1, requeued
            stack.start_worker("restarted")
            finals = [wait_for_job(client, job_id, timeout=240) for job_id in (first, *waiting)]
    finally:
        stack.stop()
        broker.stop()
    assert [f["state"] for f in finals] == ["succeeded"] * 3, finals
    assert finals[0]["attempts"] == 2
    assert finals[0]["started_at"] < min(f["started_at"] for f in finals[1:]), finals
