"""Two API processes and two fnsi-worker processes, each on a data folder of its own,
sharing only PostgreSQL (records, blobs and artefacts) and Redis, as on four machines.

The end-to-end flow runs through both APIs in turn (each request to the next one, as
behind a load balancer): a simulation and an identification computed on whichever worker
takes them, every artefact downloaded through either API, a study revised twice at once.
Then every kind of process is killed and restarted while jobs run (a worker, an API,
Redis, PostgreSQL): every job still succeeds, and none completes twice.
"""

from __future__ import annotations

import re
import time
from collections import Counter
from collections.abc import Iterator

import psycopg
import pytest

from tests.service.hosts import Deployment, PrivatePostgres
from tests.service.servers import wait_for_job, wait_for_progress

# The end-to-end tests, run here on this module's `stack`: the two-host deployment.
from tests.service.test_end_to_end import (  # noqa: F401
    IDENTIFICATION,
    datasets,
    identified,
    test_a_running_job_cancels_within_seconds,
    test_every_artefact_downloads,
    test_health_reports_the_execution_mode,
    test_identification_result_matches_the_simulated_truth,
)
from tests.service.test_faults import LONG, simulation
from tests.service.test_faults import broker as broker


@pytest.fixture(scope="module")
def postgres() -> Iterator[PrivatePostgres]:
    server = PrivatePostgres.create()
    server.start()
    yield server
    server.remove()


@pytest.fixture(scope="module")
def stack(tmp_path_factory, postgres, broker) -> Iterator[Deployment]:
    """2 APIs and 2 workers; a job may lose up to 3 attempts (a killed worker, then lost
    leases while PostgreSQL restarts) before it fails."""
    deployment = Deployment(tmp_path_factory.mktemp("hosts"), {
        "FNSI_BROKER_URL": broker.url, "FNSI_DATABASE_URL": postgres.url,
        "FNSI_BLOB_STORE": "database", "FNSI_QUEUE_NAME": "fnsi-hosts",
        "FNSI_MAX_ATTEMPTS": "4", "FNSI_REQUEUE_AFTER": "5"})
    try:
        for _ in range(2):
            deployment.add_api()
            deployment.add_worker()
        yield deployment
    finally:
        deployment.stop()


def test_each_host_keeps_its_own_folder(stack):
    folders = {host.data_dir for host in [*stack.apis, *stack.workers]}
    assert len(folders) == 4
    assert not any((folder / "fnsi.sqlite3").exists() for folder in folders)


def test_killing_every_kind_of_process_loses_no_job_and_runs_none_twice(stack, postgres,
                                                                        broker):
    with stack.client() as client:
        long_jobs = [simulation(client, **LONG, seed=s) for s in (21, 22)]
        short_jobs = [simulation(client, seed=s) for s in range(23, 29)]
        wait_for_progress(client, long_jobs[0], 0.05)
    host = stack.workers[0]
    host.kill_worker(host.workers[0])  # with its job, if it ran one
    host.start_worker("w0-again")
    stack.apis[0].kill_api()
    stack.apis[0].start_api()
    broker.kill()
    broker.start()
    postgres.kill()  # while jobs run: their leases lapse, their outcomes wait
    time.sleep(1.0)
    postgres.start()
    job_ids = [*long_jobs, *short_jobs]
    with stack.client() as client:
        finals = [wait_for_job(client, job_id, timeout=300) for job_id in job_ids]
    assert [f["state"] for f in finals] == ["succeeded"] * len(job_ids), finals
    # None ran twice: one attempt of each job stored an outcome, one dataset each.
    stored = Counter(re.findall(r"job (job_\w+) attempt \d+ stored its outcome",
                                stack.worker_logs()))
    assert {job_id: stored[job_id] for job_id in job_ids} == dict.fromkeys(job_ids, 1)
    with psycopg.connect(postgres.url) as db:
        produced = dict(db.execute("SELECT source_job, count(*) FROM datasets WHERE "
                                   "source_job = ANY(%s) GROUP BY source_job", (job_ids,)))
    assert produced == dict.fromkeys(job_ids, 1)


def test_a_study_is_created_and_revised_through_both_apis_on_either_worker(
        stack, datasets):  # noqa: F811 (the imported fixture)
    """Study snapshots and their lock live in PostgreSQL: two revisions asked at once apply
    one after the other whichever host computes them, and any API shows the history."""
    estimation, validation = datasets
    linear = {key: value for key, value in IDENTIFICATION.items() if key != "elements"}
    with stack.client() as client:
        created = client.post("/v1/studies", json={
            **linear, "order": 4, "dataset_id": estimation,
            "validation_dataset_id": validation, "name": "two hosts"})
        assert created.status_code == 202, created.text
        study_id = created.json()["id"]
        revisions = [client.post(f"/v1/studies/{study_id}/revisions", json=body).json()["id"]
                     for body in ({"add": IDENTIFICATION["elements"], "note": "cubic"},
                                  {"order": 6})]
        finals = [wait_for_job(client, job_id) for job_id in revisions]
        assert [f["state"] for f in finals] == ["succeeded"] * 2, finals
        views = [client.get(f"/v1/studies/{study_id}").json() for _ in stack.apis]
    assert views[0] == views[1]
    history = views[0]["history"]
    assert [row["note"] for row in history] == ["starting model", "cubic", "order 6"]
    # the cubic spring of the simulated chain explains most of the linear model's error
    assert history[1]["nrmse_percent"] < history[0]["nrmse_percent"]
    # the order change was computed on top of the cubic revision, not beside it
    assert [e["kind"] for e in views[0]["revisions"][2]["elements"]] == ["polynomial"]
