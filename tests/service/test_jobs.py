"""Batches (idempotent), job listing with filters and cursors, cancel of queued jobs,
typed job results."""

from __future__ import annotations

import json
import time
from datetime import UTC, datetime, timedelta

import pytest
from sqlalchemy import update

from service import schema
from service.schemas.jobs import Job
from service.schemas.results import (
    DiagnosisJobResult,
    IdentificationJobResult,
    SimulationJobResult,
    StudyJobResult,
)
from service.store import JobState

SIM = {"kind": "simulation", "request": {"preset": "single", "periods": 3,
                                         "samples_per_period": 2500}}


def batch(client, jobs, key=None):
    headers = {"Idempotency-Key": key} if key else {}
    return client.post("/v1/batches", json={"jobs": jobs}, headers=headers)


def test_retried_batch_with_idempotency_key_returns_the_first_answer(client):
    first = batch(client, [SIM, SIM], key="run-42")
    again = batch(client, [SIM, SIM], key="run-42")
    assert first.status_code == again.status_code == 202
    assert again.json()["id"] == first.json()["id"]
    assert again.json()["job_ids"] == first.json()["job_ids"]
    assert again.headers["Idempotent-Replayed"] == "true"
    listed = client.get("/v1/jobs?kind=simulation&limit=200").json()["items"]
    assert len(listed) == 2  # the retry submitted nothing


def test_idempotency_key_reused_for_another_body_is_409(client):
    batch(client, [SIM], key="k1")
    response = batch(client, [SIM, SIM], key="k1")
    assert response.status_code == 409
    assert response.headers["content-type"] == "application/problem+json"


def test_batch_with_one_invalid_job_submits_nothing(client):
    bad = {"kind": "identification", "request": {"dataset_id": "ds_none", "band": [5, 50],
                                                 "block_rows": 10}}
    response = batch(client, [SIM, bad])
    assert response.status_code == 422
    assert response.json()["detail"].startswith("jobs[1].request.dataset_id")
    assert client.get("/v1/jobs").json()["items"] == []


def test_job_pages_follow_cursors_newest_first(client):
    ids = batch(client, [SIM] * 5).json()["job_ids"]
    seen, cursor = [], None
    while True:
        page = client.get("/v1/jobs", params={"limit": 2, "kind": "simulation",
                                              **({"cursor": cursor} if cursor else {})}).json()
        seen += [job["id"] for job in page["items"]]
        cursor = page["next_cursor"]
        if cursor is None:
            break
    assert seen == ids[::-1]
    assert client.get("/v1/jobs?kind=identification").json()["items"] == []
    assert client.get("/v1/jobs?cursor=garbage").status_code == 422
    assert client.get("/v1/jobs?state=nonsense").status_code == 422


def test_batch_view_counts_states(client):
    body = batch(client, [SIM, SIM]).json()
    view = client.get(f"/v1/batches/{body['id']}").json()
    assert sum(view["counts"].values()) == 2 and len(view["jobs"]) == 2


def test_cancel_of_a_queued_job_is_immediate(client):
    client.app.state.queue.stop()  # nothing may start the job
    store = client.app.state.store
    job = store.create_job("public", "simulation", SIM["request"])
    response = client.delete(f"/v1/jobs/{job.id}")
    assert response.status_code == 202
    assert response.json()["state"] == JobState.CANCELLED
    # the job is finished now: a second DELETE deletes it
    assert client.delete(f"/v1/jobs/{job.id}").status_code == 204
    assert client.get(f"/v1/jobs/{job.id}").status_code == 404


def finished_job(client, kind="simulation", request=None, *, days_ago=0.0):
    """A job of the public owner that succeeded ``days_ago`` days ago, with an artefact."""
    store = client.app.state.store
    job = store.create_job("public", kind, request or SIM["request"])
    store.write_artefact(job.id, "result.json", b"{}")
    # the result a simulation stores (the others' are not read by these tests)
    result = {"dataset_id": "ds_00000000000000000000"} if kind == "simulation" else None
    store.finish(job.id, JobState.SUCCEEDED, result=result)
    finished = datetime.now(UTC) - timedelta(days=days_ago)
    with store.db.transaction() as db:
        db.execute(update(schema.jobs).where(schema.jobs.c.id == job.id).values(
            finished_at=finished.isoformat(timespec="milliseconds")))
    return job


def test_delete_of_a_finished_job_removes_its_record_and_artefacts(client):
    client.app.state.queue.stop()
    store = client.app.state.store
    job, other = finished_job(client), finished_job(client)
    queued = store.create_job("public", "simulation", SIM["request"])
    batch_id = batch(client, [SIM]).json()["id"]
    in_batch = store.get_batch(batch_id).job_ids[0]
    store.finish(in_batch, JobState.FAILED, error="no")
    for job_id in (job.id, in_batch):
        assert client.delete(f"/v1/jobs/{job_id}").status_code == 204
        assert client.get(f"/v1/jobs/{job_id}").status_code == 404
        assert client.get(f"/v1/jobs/{job_id}/artefacts").status_code == 404
        assert not store.artefact_dir(job_id).exists()
    assert client.delete(f"/v1/jobs/{job.id}").status_code == 404
    # the batch shows what is left of it; other jobs and scratch space are untouched
    view = client.get(f"/v1/batches/{batch_id}").json()
    assert view["job_ids"] == [in_batch] and view["jobs"] == [] and view["counts"] == {}
    assert client.get(f"/v1/jobs/{other.id}/artefacts/result.json").content == b"{}"
    assert client.get(f"/v1/jobs/{queued.id}").json()["state"] == JobState.QUEUED
    # an artefact being downloaded (opened) when its job is deleted is still sent whole
    with store.open_artefact(other.id, "result.json") as sending:
        assert client.delete(f"/v1/jobs/{other.id}").status_code == 204
        assert sending.read() == b"{}"
    assert list(store.tmp.iterdir()) == []


def test_a_finished_job_of_a_study_is_kept_with_the_study(client):
    client.app.state.queue.stop()
    job = finished_job(client, "study_revision", {"study_id": "study_1"})
    response = client.delete(f"/v1/jobs/{job.id}")
    assert response.status_code == 409
    assert "study_1" in response.json()["detail"]
    assert client.get(f"/v1/jobs/{job.id}/artefacts/result.json").status_code == 200


def test_the_supervisor_deletes_jobs_finished_beyond_the_retention(make_client):
    client = make_client(job_retention_days=1.0, supervisor_interval=0.1)
    client.app.state.queue.stop()  # nothing may start the queued job
    store = client.app.state.store
    expired = finished_job(client, days_ago=1.01)
    recent = finished_job(client, days_ago=0.99)
    study_job = finished_job(client, "study_revision", {"study_id": "study_1"}, days_ago=9)
    queued = store.create_job("public", "simulation", SIM["request"])
    deadline = time.monotonic() + 30
    while store.get_job(expired.id) is not None:
        assert time.monotonic() < deadline, "the supervisor kept an expired job"
        time.sleep(0.1)
    assert not store.artefact_dir(expired.id).exists()
    for kept in (recent, study_job, queued):
        assert store.get_job(kept.id) is not None
    assert store.list_artefacts(recent.id) == [("result.json", 2)]


def test_without_a_retention_setting_finished_jobs_stay(make_client):
    client = make_client(supervisor_interval=0.1)
    client.app.state.queue.stop()
    old = finished_job(client, days_ago=10_000)
    time.sleep(0.5)  # several supervisor passes
    assert client.get(f"/v1/jobs/{old.id}").status_code == 200


IDENTIFIED = {
    "order": 2, "modes": [{"frequency_hz": 13.0, "damping_ratio": 0.01,
                           "shape": [[1.0, 0.0]], "confirmed": None}],
    "output_names": ["x1"],
    "coefficients": [{"name": "k3", "element": 0, "basis": 0, "method": "fnsi",
                      "identifiable": False, "reason": "no motion at x1"}],
    "stiffness": [], "timings_s": {"fnsi": 0.5}, "settings": None,
    "errors": {"estimation": {"failure": "the model is unstable"}}, "later_field": [1, 2]}
REVISED = {"study_id": "study_1", "revision": 0, "revision_summary": {
    "number": 0, "note": "starting model", "order": "auto", "identified_order": 2,
    "elements": [], "coefficients": [], "modal": {"frequency_hz": [13.0], "damping_ratio": [0.01]},
    "nrmse_percent": None, "noise_floor_percent": None, "validation": None,
    "failure": "unstable"}, "history": []}
DIAGNOSED = {"study_id": "study_1", "revision": 0, "nrmse_before_percent": 2.5,
             "noise_floor_percent": 0.4, "found": False, "summary": "nothing found",
             "candidates": [], "notes": [], "timings": {"screening": 1.5}}


@pytest.mark.parametrize(("kind", "result", "model"), [
    ("simulation", {"dataset_id": "ds_1"}, SimulationJobResult),
    ("identification", IDENTIFIED, IdentificationJobResult),
    ("study_revision", REVISED, StudyJobResult),
    ("study_diagnosis", DIAGNOSED, DiagnosisJobResult),
    # a document of no known shape (e.g. from an older worker) is still served
    ("identification", {"legacy": True, "order": "unknown"}, dict)])
def test_job_result_is_typed_by_its_kind_and_returned_unchanged(kind, result, model):
    result = {**result, "kind": kind}  # what Job.of serves: the document and the job's kind
    job = Job(id="job_1", kind=kind, state=JobState.SUCCEEDED, progress=1.0, message="done",
              created_at="2026-01-01T00:00:00Z", attempts=1, request={}, result=result)
    again = Job.model_validate(job.model_dump())  # as FastAPI validates a response
    assert isinstance(again.result, model)
    # Unknown keys kept, absent optional fields not added, ints not made floats.
    returned = json.loads(again.model_dump_json())["result"]
    assert json.dumps(returned, sort_keys=True) == json.dumps(result, sort_keys=True)
