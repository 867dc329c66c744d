"""A modelling study run by a real fnsi-worker over Redis (Celery), not the embedded runner.

The same flow as :mod:`tests.service.test_studies` (create, diagnose, add the top
candidate), checked for what differs with a separate worker process: the study jobs are
routed to the worker, their results and artefacts reach the API through the shared data
directory, and the study snapshot the worker saves is what the API serves.
"""

from __future__ import annotations

import pytest

from tests.fnsi.test_diagnosis import REDUCTION
from tests.service.servers import celery_stack, wait_for_job
from tests.service.test_studies import EFFORT, MODEL, PNG, _upload, records  # noqa: F401


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    with celery_stack(tmp_path_factory.mktemp("studies-celery") / "data") as running:
        yield running


def test_study_jobs_run_on_the_celery_worker(stack, records):  # noqa: F811
    estimation, validation = records
    with stack.client() as client:
        health = client.get("/health").json()
        assert health["queue"] == "celery", health
        created = client.post("/v1/studies", json={
            **MODEL, "dataset_id": _upload(client, estimation),
            "validation_dataset_id": _upload(client, validation), "name": "chain on celery"})
        assert created.status_code == 202, created.text
        study_id = created.json()["id"]
        diagnosis = client.post(f"/v1/studies/{study_id}/diagnoses", json=EFFORT)
        assert diagnosis.status_code == 202, diagnosis.text
        diagnosis = wait_for_job(client, diagnosis.json()["id"])
        assert diagnosis["state"] == "succeeded", diagnosis
        top = diagnosis["result"]["candidates"][0]
        assert (top["effect"], top["element"]["dof"], top["element"]["ref"]) == (
            "clearance", "x4", "x5")
        revision = client.post(f"/v1/studies/{study_id}/revisions",
                               json={"add": [top["element"]], "note": "clearance"})
        assert revision.status_code == 202, revision.text
        assert wait_for_job(client, revision.json()["id"])["state"] == "succeeded"

        study = client.get(f"/v1/studies/{study_id}").json()
        history = study["history"]
        assert [row["note"] for row in history] == ["starting model", "clearance"]
        assert history[0]["nrmse_percent"] / history[1]["nrmse_percent"] >= REDUCTION
        for link in (study["history_chart"], *study["revisions"][1]["artefacts"].values()):
            response = client.get(link)
            assert response.status_code == 200, link
        assert client.get(study["history_chart"]).content.startswith(PNG)
    # study, diagnosis and revision ran in the worker (the API has no runner of its own)
    worker_log = (stack.data_dir.parent / "worker-w0.log").read_text()
    assert worker_log.count("Task fnsi.run_job") >= 6, worker_log[-2000:]
