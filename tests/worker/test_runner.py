"""The job runner and the store's claim/lease protocol, with small task functions."""

from __future__ import annotations

import threading
import time

import pytest
from sqlalchemy import update

from service.schema import jobs
from service.settings import Settings
from service.store import JobState, LeaseLostError, Store
from worker.runner import run_job


@pytest.fixture
def settings(tmp_path, database) -> Settings:
    """Short leases, on each record store (the claim and lease contract is the store's)."""
    return Settings(data_dir=tmp_path, lease_seconds=1.0, max_attempts=2, job_time_limit=30.0,
                    database_url=database())


@pytest.fixture
def store(settings) -> Store:
    return Store.from_settings(settings)


def counting_task(steps: int, pause: float):
    """A task that reports progress ``steps`` times and returns how far it got."""
    def task(context):
        for k in range(steps):
            context.progress((k + 1) / steps, f"step {k + 1} of {steps}")
            time.sleep(pause)
        return {"steps": steps}
    return task


def test_claim_is_exclusive_while_the_lease_lives(store):
    job = store.create_job("me", "simulation", {})
    first = store.claim(job.id, lease_seconds=30, max_attempts=2)
    second = store.claim(job.id, lease_seconds=30, max_attempts=2)
    assert first.run and first.attempt == 1
    assert not second.run and 29 < second.retry_after <= 30
    store.finish(job.id, JobState.SUCCEEDED, result={})
    assert store.claim(job.id, lease_seconds=30, max_attempts=2).reason == "already succeeded"


def test_expired_lease_is_requeued_then_failed_after_max_attempts(store):
    job = store.create_job("me", "simulation", {})
    for attempt in (1, 2):
        assert store.claim(job.id, lease_seconds=0.01, max_attempts=2).attempt == attempt
        time.sleep(0.02)
        requeued = store.reap_lost(max_attempts=2)
        if attempt == 1:
            assert requeued == [job.id]
            assert store.get_job(job.id).state == JobState.QUEUED
    final = store.get_job(job.id)
    assert final.state == JobState.FAILED and "2 attempts" in final.error


def test_run_records_progress_and_result(store, settings):
    job = store.create_job("me", "simulation", {})
    run_job(job.id, settings, {"simulation": counting_task(5, 0.0)})
    done = store.get_job(job.id)
    assert done.state == JobState.SUCCEEDED and done.result == {"steps": 5}
    assert done.progress == 1.0 and done.lease_until is None


def test_cancel_stops_a_running_task_within_a_second(store, settings):
    job = store.create_job("me", "simulation", {})
    runner = threading.Thread(target=run_job, args=(
        job.id, settings, {"simulation": counting_task(1000, 0.01)}))
    runner.start()
    while store.get_job(job.id).state != JobState.RUNNING:
        time.sleep(0.01)
    time.sleep(0.3)
    asked = time.monotonic()
    store.request_cancel(job.id)
    runner.join(timeout=5)
    assert time.monotonic() - asked < 1.0
    cancelled = store.get_job(job.id)
    assert cancelled.state == JobState.CANCELLED and 0 < cancelled.progress < 1


def test_time_limit_fails_the_job_with_a_reason(store, settings):
    settings = settings.model_copy(update={"job_time_limit": 0.2})
    job = store.create_job("me", "simulation", {})
    run_job(job.id, settings, {"simulation": counting_task(100, 0.01)})
    failed = store.get_job(job.id)
    assert failed.state == JobState.FAILED and "FNSI_JOB_TIME_LIMIT" in failed.error


def test_library_value_error_becomes_the_job_error(store, settings):
    def bad(context):
        raise ValueError("block_rows too small; raise it above 12")
    job = store.create_job("me", "identification", {})
    run_job(job.id, settings, {"identification": bad})
    assert store.get_job(job.id).error == "block_rows too small; raise it above 12"


def test_heartbeat_keeps_a_silent_task_alive(store, settings):
    def silent(context):
        time.sleep(2.5 * settings.lease_seconds)  # no progress reports at all
        return {}
    job = store.create_job("me", "simulation", {})
    runner = threading.Thread(target=run_job, args=(job.id, settings, {"simulation": silent}))
    runner.start()
    time.sleep(2 * settings.lease_seconds)
    assert store.reap_lost(max_attempts=2) == []
    runner.join()
    assert store.get_job(job.id).state == JobState.SUCCEEDED


def test_queued_jobs_whose_message_may_be_lost_are_found_with_their_real_age(store):
    job = store.create_job("me", "simulation", {})
    time.sleep(0.2)
    (never,) = store.stale_queued(older_than=60)  # never handed over
    assert never.id == job.id and never.published_ago is None
    assert 0.2 <= never.created_ago < 5
    store.mark_enqueued(job.id)
    assert store.stale_queued(older_than=60) == []
    (published,) = store.stale_queued(older_than=0)
    assert published.id == job.id and 0 <= published.published_ago < 5


def test_an_attempt_that_lost_its_job_stops_and_stores_nothing(store, settings):
    """The job was re-queued while its attempt ran (its lease lapsed while the database
    was out of reach): the attempt stops at its next report and never finishes the job."""
    job = store.create_job("me", "simulation", {})

    def requeued_meanwhile(context):
        context.progress(0.1, "started")
        with store.db.transaction() as db:  # what the supervisor's reap_lost does
            db.execute(update(jobs).where(jobs.c.id == job.id).values(
                state=JobState.QUEUED.value, lease_until=None))
        for k in range(100):
            context.progress(0.2 + k / 200, "still going")
            time.sleep(0.01)
        return {"ran": "to the end"}

    run_job(job.id, settings, {"simulation": requeued_meanwhile})
    after = store.get_job(job.id)
    assert after.state == JobState.QUEUED and after.result is None, after


def test_finishing_needs_the_attempt_that_runs_the_job(store):
    job = store.create_job("me", "simulation", {})
    assert store.claim(job.id, lease_seconds=30, max_attempts=3).attempt == 1
    with pytest.raises(LeaseLostError):
        store.finish(job.id, JobState.SUCCEEDED, result={}, attempt=2)
    with pytest.raises(LeaseLostError):
        store.report(job.id, lease_seconds=30, attempt=2)
    store.finish(job.id, JobState.SUCCEEDED, result={}, attempt=1)
    assert store.get_job(job.id).state == JobState.SUCCEEDED
