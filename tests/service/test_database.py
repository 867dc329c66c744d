"""The record store under concurrency, on SQLite and PostgreSQL; the schema migration of a
SQLite store made before the schema had a version; blobs, artefacts and studies shared
through PostgreSQL."""

from __future__ import annotations

import json
import sqlite3
import threading
from collections import Counter
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from pydantic import ValidationError
from sqlalchemy import select, text

from fnsi.measurement import Measurement
from service.schema import VERSION, objects, schema_version
from service.settings import Settings
from service.store import JobState, Store
from service.study_store import StudyStore
from tests.service.servers import free_port

# Enough simultaneous callers that, without row locks, two of them would read the same
# queued job before either writes (each claim is a read, a decision and a write).
CALLERS = 8


@pytest.fixture
def store(tmp_path, database) -> Store:
    return Store(tmp_path / "data", database())


def test_each_job_is_claimed_once_by_concurrent_workers(store):
    job_ids = [store.create_job("me", "simulation", {"n": k}).id for k in range(40)]

    def claim_all(_: int) -> list[str]:
        return [j for j in job_ids
                if store.claim(j, lease_seconds=60, max_attempts=2).run]

    with ThreadPoolExecutor(CALLERS) as pool:
        claimed = [j for won in pool.map(claim_all, range(CALLERS)) for j in won]
    assert Counter(claimed) == Counter(job_ids)  # every job once, none twice
    assert {store.get_job(j).attempts for j in job_ids} == {1}


def test_a_retried_batch_is_created_once_under_concurrent_retries(store):
    jobs = [("simulation", {"preset": "single"})] * 3
    together = threading.Barrier(CALLERS)

    def retry(_: int):
        together.wait()
        return store.create_batch("me", jobs, idempotency_key="k1")

    with ThreadPoolExecutor(CALLERS) as pool:
        answers = list(pool.map(retry, range(CALLERS)))
    assert sum(created for _, created in answers) == 1
    assert len({batch.id for batch, _ in answers}) == 1
    assert len(store.list_jobs("me", limit=100)) == 3


def test_reaping_and_claiming_a_lost_job_together_run_it_once(store):
    job = store.create_job("me", "simulation", {})
    store.claim(job.id, lease_seconds=-1, max_attempts=3)  # its worker died at once
    barrier = threading.Barrier(2)

    def reap() -> list[str]:
        barrier.wait()
        return store.reap_lost(max_attempts=3)

    def claim() -> bool:
        barrier.wait()
        return store.claim(job.id, lease_seconds=60, max_attempts=3).run

    with ThreadPoolExecutor(2) as pool:
        reaped, claimed = pool.submit(reap), pool.submit(claim)
        reaped, claimed = reaped.result(), claimed.result()
    final = store.get_job(job.id)
    # Either the claim took the expired lease (running, attempt 2) and the reaper found
    # nothing, or the reaper re-queued it first and the claim then started attempt 2.
    assert claimed and final.state == JobState.RUNNING and final.attempts == 2, final
    assert reaped in ([], [job.id])


def test_a_held_lock_excludes_other_holders_until_released(store, tmp_path):
    order, inside = [], threading.Event()
    lock_file = tmp_path / "lock"

    def hold() -> None:
        with store.db.held_lock("study:x", lock_file, wait=lambda: None):
            order.append("first in")
            inside.set()
            threading.Event().wait(1.0)
            order.append("first out")

    first = threading.Thread(target=hold)
    first.start()
    inside.wait(5)
    with store.db.held_lock("study:x", lock_file, wait=lambda: order.append("waited")):
        order.append("second in")
    first.join()
    assert order[0] == "first in" and "waited" in order
    assert order.index("first out") < order.index("second in")


# The schema of a store made before versions (service/store.py until issue 24).
_VERSION_1 = """
CREATE TABLE blobs (digest TEXT PRIMARY KEY, summary TEXT NOT NULL, size INTEGER NOT NULL);
CREATE TABLE uploads (upload_key TEXT PRIMARY KEY, digest TEXT NOT NULL REFERENCES blobs(digest));
CREATE TABLE datasets (
    id TEXT PRIMARY KEY, owner TEXT NOT NULL, digest TEXT NOT NULL REFERENCES blobs(digest),
    name TEXT NOT NULL, source_job TEXT, created_at TEXT NOT NULL);
CREATE INDEX datasets_by_owner ON datasets(owner);
CREATE TABLE jobs (
    seq INTEGER PRIMARY KEY AUTOINCREMENT, id TEXT UNIQUE NOT NULL, owner TEXT NOT NULL,
    kind TEXT NOT NULL, state TEXT NOT NULL, progress REAL NOT NULL DEFAULT 0,
    message TEXT NOT NULL DEFAULT '', request TEXT NOT NULL, result TEXT, error TEXT,
    created_at TEXT NOT NULL, started_at TEXT, finished_at TEXT,
    attempts INTEGER NOT NULL DEFAULT 0, lease_until REAL,
    cancel_requested INTEGER NOT NULL DEFAULT 0, batch_id TEXT, enqueued_at REAL);
CREATE INDEX jobs_by_owner ON jobs(owner, seq);
CREATE INDEX jobs_by_state ON jobs(state);
CREATE INDEX jobs_by_finish ON jobs(finished_at);
CREATE TABLE batches (
    id TEXT PRIMARY KEY, owner TEXT NOT NULL, idempotency_key TEXT, request_hash TEXT NOT NULL,
    job_ids TEXT NOT NULL, created_at TEXT NOT NULL, UNIQUE (owner, idempotency_key));
"""


def test_a_store_from_before_schema_versions_is_migrated_keeping_ids_and_cursors(tmp_path):
    data = tmp_path / "data"
    data.mkdir()
    (data / "store-id").write_text("store_0123456789abcdef0123")
    with sqlite3.connect(data / "fnsi.sqlite3") as old:
        old.executescript(_VERSION_1)
        old.execute("INSERT INTO blobs VALUES ('d1', '{}', 10)")
        for k in range(5):  # rowids 1..5, with a gap left by a deleted dataset
            old.execute("INSERT INTO datasets VALUES (?, 'me', 'd1', ?, NULL, '2026-01-01')",
                        (f"ds_{k}", f"n{k}"))
        old.execute("DELETE FROM datasets WHERE id = 'ds_2'")
        old.execute("INSERT INTO jobs (id, owner, kind, state, request, created_at) VALUES "
                    "('job_a', 'me', 'study_revision', 'queued', ?, '2026-01-01')",
                    (json.dumps({"study_id": "study_x", "outputs": []}),))
        old.execute("INSERT INTO jobs (id, owner, kind, state, request, created_at, "
                    "cancel_requested) VALUES ('job_b', 'me', 'simulation', 'running', '{}', "
                    "'2026-01-01', 1)")
    store = Store(data)
    with store.db.read() as db:
        assert db.execute(select(schema_version.c.version)).scalar_one() == VERSION
    listed = store.list_datasets("me")
    assert [(d.id, d.seq) for d in listed] == [("ds_4", 5), ("ds_3", 4), ("ds_1", 2),
                                               ("ds_0", 1)]
    assert [d.id for d in store.list_datasets("me", before_seq=4)] == ["ds_1", "ds_0"]
    assert [j.id for j in store.jobs_of_study("study_x", "me")] == ["job_a"]
    assert store.get_job("job_b").cancel_requested is True
    assert store.instance_id == "store_0123456789abcdef0123"
    assert store.create_job("me", "simulation", {}).seq == 3  # after the old jobs


@pytest.fixture
def two_hosts(tmp_path, postgres_schemas) -> tuple[Store, Store]:
    """Two stores on separate data folders sharing one PostgreSQL database and its blobs,
    as an API and a worker on two machines."""
    url = postgres_schemas()
    return (Store(tmp_path / "host-a", url, "database"),
            Store(tmp_path / "host-b", url, "database"))


def test_blobs_and_artefacts_written_on_one_host_are_read_on_another(two_hosts):
    a, b = two_hosts
    # 300,000 samples: the blob spans several chunks of the object store.
    rng = np.random.default_rng(0)
    measurement = Measurement.from_arrays(rng.standard_normal(300_000),
                                          rng.standard_normal((300_000, 2)), fs=100.0)
    dataset = a.put_measurement(measurement, owner="me", name="rec")
    loaded = b.load_measurement(dataset.id)
    np.testing.assert_array_equal(loaded.y, measurement.y)  # bit for bit: a copy of a file
    with a.open_blob(dataset) as sent, b.open_blob(b.get_dataset(dataset.id)) as received:
        assert sent.read() == received.read()
    job = a.create_job("me", "simulation", {})
    b.write_artefact(job.id, "result.json", b'{"attempt": 1}')
    assert a.list_artefacts(job.id) == [("result.json", 14)]
    b.write_artefact(job.id, "result.json", b'{"attempt": 2}')  # a new attempt replaces it
    with a.open_artefact(job.id, "result.json") as file:
        assert file.read() == b'{"attempt": 2}'


def test_deleting_on_one_host_removes_the_shared_objects(two_hosts):
    a, b = two_hosts
    measurement = Measurement.from_arrays(np.ones(8), np.zeros((8, 2)), fs=100.0, periods=2)
    dataset = a.put_measurement(measurement, owner="me", name="rec")
    job = a.create_job("me", "simulation", {})
    a.write_artefact(job.id, "truth.json", b"{}")
    a.finish(job.id, JobState.SUCCEEDED, result={})
    with a.db.read() as db:
        oids = [int(oid) for oid in db.execute(select(objects.c.oid)).scalars()]
    assert len(oids) == 2
    b.delete_dataset(dataset.id)
    assert b.delete_job(job.id)
    with a.db.read() as db:
        assert db.execute(select(objects.c.key)).all() == []
        left = text("SELECT count(*) FROM pg_largeobject_metadata WHERE oid::bigint = ANY(:o)")
        assert db.execute(left, {"o": oids}).scalar() == 0  # the contents are gone too
    assert a.list_artefacts(job.id) == [] and a.open_artefact(job.id, "truth.json") is None
    with pytest.raises(ValueError, match="does not exist"):
        b.load_measurement(dataset.id)


def test_shared_blobs_need_postgresql(tmp_path):
    with pytest.raises(ValueError, match="FNSI_DATABASE_URL=postgresql"):
        Store(tmp_path, None, "database")


class _Snapshot:
    """Stands in for fnsi.study.Study: ``save`` writes study.json, all StudyStore reads."""

    def __init__(self, revisions: int) -> None:
        self.revisions = [None] * revisions

    def save(self, folder) -> None:
        (folder / "study.json").write_text(json.dumps({"revisions": len(self.revisions)}))


def test_a_study_made_on_one_host_is_read_and_revised_on_another(two_hosts):
    a, b = (StudyStore(store) for store in two_hosts)
    study = a.create("me", "chain", {"order": 4})
    assert b.get(study.id) == study and b.owned_by("me") == [study]
    assert b.owned_by("someone else") == []
    b.save(study.id, _Snapshot(1), ["job_1"])  # revision 0, computed on host b
    assert a.snapshot(study.id).study == {"revisions": 1}
    for count in (2, 3):
        a.save(study.id, _Snapshot(count), ["job"] * count)
    seen = b.snapshot(study.id)
    assert seen.study == {"revisions": 3} and seen.producers == ["job"] * 3
    # the oldest snapshot is pruned from the shared objects too
    assert sorted({name.split("/")[0] for name in b.store.shared_files(b.folder(study.id))
                   if "/" in name}) == ["revisions-2", "revisions-3"]


def test_a_database_url_of_another_kind_or_out_of_reach_says_what_to_change(tmp_path):
    with pytest.raises(ValidationError, match="must start with postgresql://"):
        Settings(database_url="mysql://fnsi@db/fnsi")
    with pytest.raises(RuntimeError, match="start it, or correct FNSI_DATABASE_URL") as err:
        Store(tmp_path, f"postgresql://fnsi:secret@127.0.0.1:{free_port()}/fnsi")
    assert "secret" not in str(err.value)  # the password is not shown


def test_a_shared_study_snapshot_is_never_overwritten(two_hosts):
    """Two revisions that both computed revision 1 (one lost the study's lock when the
    database restarted): the second to save fails instead of replacing the first."""
    a, b = (StudyStore(store) for store in two_hosts)
    study = a.create("me", "chain", {})
    a.save(study.id, _Snapshot(1), ["job_a"])
    with pytest.raises(FileExistsError):
        b.save(study.id, _Snapshot(1), ["job_b"])
    assert b.snapshot(study.id).producers == ["job_a"]
    assert list(b.store.tmp.iterdir()) == []
