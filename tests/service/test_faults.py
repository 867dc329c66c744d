"""Faults around the jobs: the broker restarted, the API restarted, the disk full.

In every case each accepted job ends in a terminal state or is still queued, and no
completed result is lost. (A worker killed mid-job: tests/worker/test_worker_loss.py; the
API killed in embedded mode: tests/service/test_restart.py.)
"""

from __future__ import annotations

import io
import re
import signal
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from service.schemas.simulations import ModelSimulation
from service.settings import Settings
from service.store import JobState, Store
from tests.redis_server import redis_answers, redis_server_binary
from tests.service import formats
from tests.service.servers import Stack, free_port, start_stack, wait_for_job, wait_for_progress
from tests.service.test_simulations import REQUEST as MODEL_SIMULATION
from worker.runner import run_job
from worker.tasks import TASKS

# A few seconds of Newmark integration, reporting progress every period.
LONG = {**MODEL_SIMULATION, "periods": 100, "fs_int": 20000.0}


@dataclass
class PersistentRedis:
    """A private ``redis-server`` with an append-only file, restartable on its port."""

    port: int
    folder: Path
    process: subprocess.Popen | None = None

    @property
    def url(self) -> str:
        return f"redis://127.0.0.1:{self.port}/0"

    def start(self) -> None:
        self.process = subprocess.Popen(
            [redis_server_binary(), "--bind", "127.0.0.1", "--port", str(self.port),
             "--appendonly", "yes", "--save", "", "--dir", str(self.folder)],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 20
        while not redis_answers(self.url, timeout_s=0.2):
            assert self.process.poll() is None and time.monotonic() < deadline, "no redis"
            time.sleep(0.05)

    def kill(self) -> None:
        """SIGKILL, as a crash or an OOM kill would: only what reached the AOF survives."""
        self.process.send_signal(signal.SIGKILL)
        self.process.wait()


@pytest.fixture(scope="module")
def broker(tmp_path_factory) -> Iterator[PersistentRedis]:
    server = PersistentRedis(free_port(), tmp_path_factory.mktemp("aof"))
    server.start()
    yield server
    server.kill()


@pytest.fixture(scope="module")
def private_stack(tmp_path_factory, broker) -> Iterator[Stack]:
    """fnsi-service and one fnsi-worker on the private Redis; queued jobs whose message
    the broker lost are published again after 5 s."""
    stack = start_stack(tmp_path_factory.mktemp("faults") / "data", broker_url=broker.url,
                        workers=1, FNSI_REQUEUE_AFTER="5")
    yield stack
    stack.stop()


def simulation(client, **changes) -> str:
    response = client.post("/v1/simulations", json={**MODEL_SIMULATION, **changes})
    assert response.status_code == 202, response.text
    return response.json()["id"]


def assert_all_succeeded(client, job_ids: list[str], timeout: float = 180) -> list[dict]:
    """Every job succeeded, and the dataset each produced is there."""
    finals = [wait_for_job(client, job_id, timeout=timeout) for job_id in job_ids]
    assert [f["state"] for f in finals] == ["succeeded"] * len(finals), finals
    for final in finals:
        dataset = client.get(f"/v1/datasets/{final['result']['dataset_id']}")
        assert dataset.status_code == 200, dataset.text
    return finals


def test_broker_restart_with_jobs_running_and_queued_loses_none(private_stack, broker):
    with private_stack.client() as client:
        done = simulation(client, seed=1)
        (before,) = assert_all_succeeded(client, [done])
        running = simulation(client, **LONG)
        queued = [simulation(client, seed=s) for s in (2, 3, 4)]
        wait_for_progress(client, running, 0.05)
        broker.kill()
        # the API still answers from its store while the broker is down
        assert client.get(f"/v1/jobs/{queued[0]}").json()["state"] == "queued"
        late = client.post("/v1/simulations", json={**MODEL_SIMULATION, "seed": 5})
        time.sleep(1.0)
        broker.start()
        # the job is recorded before it is published: accepted, published once the broker
        # is back
        assert late.status_code == 202, late.text
        accepted = [running, *queued, late.json()["id"]]
        finals = assert_all_succeeded(client, accepted)
        assert finals[0]["attempts"] == 1  # the running attempt was never interrupted
        assert client.get(f"/v1/jobs/{done}").json() == before


def test_a_submission_while_the_broker_is_down_answers_at_once_and_logs_its_real_age(
        private_stack, broker):
    """Redis is down: the POST is answered without waiting for the broker, the supervisor's
    log says how long ago the job was queued (not FNSI_REQUEUE_AFTER), and the job runs
    once the broker is back."""
    with private_stack.client() as client:
        broker.kill()
        try:
            submitted = time.monotonic()
            response = client.post("/v1/simulations", json={**MODEL_SIMULATION, "seed": 9})
            took = time.monotonic() - submitted
            time.sleep(3.0)  # six supervisor passes with the broker down
        finally:
            broker.start()
        assert response.status_code == 202, response.text
        # Recording the job takes milliseconds; an unreachable Redis took 6 s to refuse.
        assert took < 1.0, f"the POST waited {took:.1f} s for the broker"
        job_id = response.json()["id"]
        assert_all_succeeded(client, [job_id])
        queued_for = time.monotonic() - submitted
    log = (private_stack.data_dir.parent / "api.log").read_text()
    ages = [float(age) for age in re.findall(
        rf"job {job_id}, queued (\d+) s ago, is not published yet", log)]
    assert ages, "the supervisor did not report the unpublished job"
    # each pass states the age at that pass: growing, never more than the job waited
    assert len(set(ages)) > 1 and max(ages) <= queued_for + 1.0, (ages, queued_for)


def test_api_restart_with_jobs_on_the_worker_loses_none(private_stack):
    with private_stack.client() as client:
        done = simulation(client, seed=6)
        (before,) = assert_all_succeeded(client, [done])
        running = simulation(client, **LONG)
        queued = [simulation(client, seed=s) for s in (7, 8)]
        wait_for_progress(client, running, 0.05)
    private_stack.kill_api()
    time.sleep(1.0)  # the worker keeps running while no API answers
    private_stack.start_api()
    with private_stack.client() as client:
        finals = assert_all_succeeded(client, [running, *queued])
        assert finals[0]["attempts"] == 1
        assert client.get(f"/v1/jobs/{done}").json() == before


@pytest.fixture
def full_disk(monkeypatch) -> None:
    """From now on every partial file the store writes is a link to /dev/full, so writing
    it fails as a full disk does (ENOSPC from the kernel)."""
    temp_path = Store.temp_path

    def on_full_disk(store: Store, suffix: str = "") -> Path:
        path = temp_path(store, suffix)
        path.unlink()
        path.symlink_to("/dev/full")
        return path

    monkeypatch.setattr(Store, "temp_path", on_full_disk)


def test_full_disk_fails_the_job_with_a_reason_and_keeps_earlier_results(tmp_path, request):
    """The disk fills while an artefact is written: that job fails saying so, the partial
    file goes, and the job, artefacts and dataset of an earlier run are untouched."""
    settings = Settings(data_dir=tmp_path / "data", broker_url=None, lease_seconds=5.0)
    store = Store(settings.data_dir)
    simulation = ModelSimulation.model_validate(MODEL_SIMULATION).model_dump(mode="json")
    earlier = store.create_job("me", "simulation", simulation)
    run_job(earlier.id, settings, TASKS)
    earlier = store.get_job(earlier.id)
    assert earlier.state == JobState.SUCCEEDED, earlier.error
    truth = (store.artefact_dir(earlier.id) / "truth.json").read_bytes()
    dataset = store.get_dataset(earlier.result["dataset_id"])
    blob = store.blob_path(dataset.digest).read_bytes()

    request.getfixturevalue("full_disk")
    job = store.create_job("me", "simulation", {**simulation, "seed": 1})
    run_job(job.id, settings, TASKS)

    failed = store.get_job(job.id)
    assert failed.state == JobState.FAILED
    assert "out of disk space" in failed.error, failed.error
    assert list(store.tmp.iterdir()) == []
    assert store.get_job(earlier.id) == earlier
    assert (store.artefact_dir(earlier.id) / "truth.json").read_bytes() == truth
    assert store.get_dataset(dataset.id) == dataset
    assert store.blob_path(dataset.digest).read_bytes() == blob


def npz_bytes(record: formats.Record, scale: float = 1.0) -> bytes:
    buffer = io.BytesIO()
    np.savez(buffer, u=scale * record.u, y=record.y, fs=np.float64(record.fs))
    return buffer.getvalue()


def test_full_disk_during_an_upload_is_507_and_keeps_earlier_datasets(make_client, request):
    client = make_client()
    record = formats.make_record()
    first = client.post("/v1/datasets", files={"file": ("a.npz", npz_bytes(record))}).json()
    request.getfixturevalue("full_disk")
    response = client.post("/v1/datasets", files={"file": ("b.npz", npz_bytes(record, 2))})
    assert response.status_code == 507, response.text
    assert response.headers["content-type"] == "application/problem+json"
    assert "out of disk space" in response.json()["detail"]
    store = client.app.state.store
    assert list(store.tmp.iterdir()) == []
    assert client.get(f"/v1/datasets/{first['id']}").json() == first
    assert client.get(f"/v1/datasets/{first['id']}/download").status_code == 200
