"""Restarting the API loses nothing: unfinished jobs of a crashed process are resumed."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

from tests.service.servers import start_stack, wait_for_job, wait_for_progress
from tests.service.test_simulations import REQUEST as MODEL_SIMULATION

LONG = {**MODEL_SIMULATION, "periods": 150, "fs_int": 20000.0}
# More than 10 s of Newmark integration on an idle machine.
LONGER = {**MODEL_SIMULATION, "periods": 300, "fs_int": 20000.0}


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


def job_processes(data_dir: Path) -> list[int]:
    """Pids of the live embedded job processes of the stack on ``data_dir`` (Linux /proc):
    processes started by multiprocessing's spawn with that FNSI_DATA_DIR."""
    marker = f"FNSI_DATA_DIR={data_dir}".encode()
    found = []
    for entry in Path("/proc").iterdir():
        try:
            if (not entry.name.isdigit() or b"spawn_main" not in (entry / "cmdline").read_bytes()
                    or marker not in (entry / "environ").read_bytes().split(b"\0")):
                continue
            if (entry / "stat").read_text().rsplit(")", 1)[1].split()[0] != "Z":
                found.append(int(entry.name))
        except OSError:  # ended meanwhile, or not ours to read
            continue
    return found


def test_job_processes_end_with_their_api_and_the_restart_keeps_the_limit(tmp_path):
    """The API alone is SIGKILLed (not its process group): its job process ends with it,
    and the restarted API resumes the job once its lease lapsed, never running more than
    FNSI_EMBEDDED_WORKERS=1 job processes."""
    data_dir = tmp_path / "data"
    stack = start_stack(data_dir, FNSI_EMBEDDED_WORKERS="1")
    try:
        with stack.client() as client:
            running = client.post("/v1/simulations", json=LONGER).json()["id"]
            queued = client.post("/v1/simulations", json=MODEL_SIMULATION).json()["id"]
            wait_for_progress(client, running, 0.05)
        assert len(job_processes(data_dir)) == 1
        os.kill(stack.api.pid, signal.SIGKILL)
        stack.api.wait()
        deadline = time.monotonic() + 5
        while job_processes(data_dir):
            assert time.monotonic() < deadline, f"job process outlived its API: {stack.data_dir}"
            time.sleep(0.1)
        stack.start_api()
        most = 0
        with stack.client() as client:
            while any(client.get(f"/v1/jobs/{j}").json()["state"] in ("queued", "running")
                      for j in (running, queued)):
                most = max(most, len(job_processes(data_dir)))
                time.sleep(0.1)
            first, second = (client.get(f"/v1/jobs/{j}").json() for j in (running, queued))
        assert most == 1
        assert first["state"] == "succeeded" and first["attempts"] == 2, first
        assert second["state"] == "succeeded" and second["attempts"] == 1, second
    finally:
        stack.stop()
