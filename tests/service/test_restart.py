"""Restarting the API loses nothing: unfinished jobs of a crashed process are resumed."""

from __future__ import annotations

from tests.service.servers import start_stack, wait_for_job, wait_for_progress
from tests.service.test_simulations import REQUEST as MODEL_SIMULATION

LONG = {**MODEL_SIMULATION, "periods": 150, "fs_int": 20000.0}


def test_jobs_of_a_crashed_api_resume_after_restart(tmp_path):
    stack = start_stack(tmp_path / "data")
    try:
        with stack.client() as client:
            running = client.post("/v1/simulations", json=LONG).json()["id"]
            queued = client.post("/v1/simulations", json=MODEL_SIMULATION).json()["id"]
            wait_for_progress(client, running, 0.1)
            assert client.get(f"/v1/jobs/{queued}").json()["state"] == "queued"
        stack.kill_api()
        stack.start_api()
        with stack.client() as client:
            first = wait_for_job(client, running, timeout=120)
            second = wait_for_job(client, queued, timeout=120)
        assert first["state"] == "succeeded" and first["attempts"] == 2, first
        assert second["state"] == "succeeded" and second["attempts"] == 1, second
    finally:
        stack.stop()
