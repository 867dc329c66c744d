"""A worker started on another FNSI_DATA_DIR than its API's returns the job's message
and consumes no more, saying why at ERROR; a worker on the right data directory then
runs the job, on its first attempt."""

from __future__ import annotations

import time

from tests.redis_server import LocalRedis
from tests.service.servers import Stack, start_stack, wait_for_job
from tests.service.test_simulations import REQUEST as MODEL_SIMULATION


def test_a_worker_on_another_data_dir_returns_the_job_and_consumes_no_more(tmp_path):
    broker = LocalRedis.start()  # private: other test runs flush the shared test database
    stack = start_stack(tmp_path / "api" / "data", broker_url=broker.url)
    foreign_dir = tmp_path / "foreign" / "data"
    foreign = Stack(stack.url, foreign_dir, {**stack.env, "FNSI_DATA_DIR": str(foreign_dir)},
                    None)
    foreign_dir.mkdir(parents=True)
    try:
        foreign.start_worker("foreign")
        with stack.client() as client:
            job_id = client.post("/v1/simulations", json=MODEL_SIMULATION).json()["id"]
            log = foreign_dir.parent / "worker-foreign.log"
            deadline = time.monotonic() + 120
            while "reject requeue=True" not in log.read_text():
                assert time.monotonic() < deadline, log.read_text()
                time.sleep(0.2)
            assert f"ERROR/ForkPoolWorker-1] FNSI_DATA_DIR {foreign_dir} is not the data " \
                "directory of the API" in log.read_text()
            assert client.get(f"/v1/jobs/{job_id}").json()["state"] == "queued"
            stack.start_worker("right")
            final = wait_for_job(client, job_id, timeout=120)
        assert final["state"] == "succeeded" and final["attempts"] == 1, final
    finally:
        foreign.stop()
        stack.stop()
        broker.stop()
