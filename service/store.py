"""Persistent store of datasets, job records, batches and artefacts under FNSI_DATA_DIR.

The store is the single source of truth for job state: the API, the embedded runner and
Celery workers all read and write it, never the broker's result backend. Records live in
one SQLite database (atomic transactions, safe across processes on one host); dataset
arrays live in content-addressed canonical NPZ files, artefacts in one folder per job.

Blobs and the upload cache are addressed by owner and content together: identical uploads
of one API key share a blob, those of two keys never do, so an upload takes the same path
and time whatever another key holds (a shared cache would tell a key, by its speed,
whether another holds a given file).

Layout::

    <data_dir>/fnsi.sqlite3          records
    <data_dir>/blobs/<digest>.npz    canonical datasets (shared by one owner's identical uploads)
    <data_dir>/blobs/<digest>.csv    CSV rendering of a blob, made on first download
    <data_dir>/jobs/<job_id>/        artefacts of a job
    <data_dir>/tmp/                  partial files, moved into place with os.replace
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import re
import secrets
import shutil
import sqlite3
import tempfile
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from datetime import UTC, datetime
from enum import StrEnum
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from fnsi.measurement import Measurement
from fnsi.summary import summarize

ARTEFACT_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,99}$")
# CSV renderings run one at a time per lock; a blob always takes the same lock.
_RENDER_LOCKS = 16

_SCHEMA = """
CREATE TABLE IF NOT EXISTS blobs (
    digest TEXT PRIMARY KEY, summary TEXT NOT NULL, size INTEGER NOT NULL);
CREATE TABLE IF NOT EXISTS uploads (
    upload_key TEXT PRIMARY KEY, digest TEXT NOT NULL REFERENCES blobs(digest));
CREATE TABLE IF NOT EXISTS datasets (
    id TEXT PRIMARY KEY, owner TEXT NOT NULL, digest TEXT NOT NULL REFERENCES blobs(digest),
    name TEXT NOT NULL, source_job TEXT, created_at TEXT NOT NULL);
CREATE INDEX IF NOT EXISTS datasets_by_owner ON datasets(owner);
CREATE TABLE IF NOT EXISTS jobs (
    seq INTEGER PRIMARY KEY AUTOINCREMENT, id TEXT UNIQUE NOT NULL, owner TEXT NOT NULL,
    kind TEXT NOT NULL, state TEXT NOT NULL, progress REAL NOT NULL DEFAULT 0,
    message TEXT NOT NULL DEFAULT '', request TEXT NOT NULL, result TEXT, error TEXT,
    created_at TEXT NOT NULL, started_at TEXT, finished_at TEXT,
    attempts INTEGER NOT NULL DEFAULT 0, lease_until REAL,
    cancel_requested INTEGER NOT NULL DEFAULT 0, batch_id TEXT, enqueued_at REAL);
CREATE INDEX IF NOT EXISTS jobs_by_owner ON jobs(owner, seq);
CREATE INDEX IF NOT EXISTS jobs_by_state ON jobs(state);
CREATE INDEX IF NOT EXISTS jobs_by_finish ON jobs(finished_at);
CREATE TABLE IF NOT EXISTS batches (
    id TEXT PRIMARY KEY, owner TEXT NOT NULL, idempotency_key TEXT, request_hash TEXT NOT NULL,
    job_ids TEXT NOT NULL, created_at TEXT NOT NULL, UNIQUE (owner, idempotency_key));
"""


class JobState(StrEnum):
    """Life cycle of a job: queued -> running -> succeeded | failed | cancelled."""

    QUEUED = "queued"
    RUNNING = "running"
    SUCCEEDED = "succeeded"
    FAILED = "failed"
    CANCELLED = "cancelled"


TERMINAL = frozenset({JobState.SUCCEEDED, JobState.FAILED, JobState.CANCELLED})


def now_iso() -> str:
    """Current UTC time, ISO 8601."""
    return datetime.now(UTC).isoformat(timespec="milliseconds")


def new_id(prefix: str) -> str:
    """Random identifier such as ``ds_3f9c...`` (prefix tells the resource)."""
    return f"{prefix}_{secrets.token_hex(10)}"


@dataclass(frozen=True)
class DatasetRecord:
    """A dataset visible to one owner; its arrays are the blob ``digest``."""

    id: str
    owner: str
    digest: str
    name: str
    created_at: str
    summary: dict[str, Any]
    size_bytes: int
    source_job: str | None = None
    seq: int = 0  # creation order (SQLite rowid), the position in listings


@dataclass(frozen=True)
class JobRecord:
    """A job as stored; ``request`` is the validated request JSON."""

    seq: int
    id: str
    owner: str
    kind: str
    state: JobState
    progress: float
    message: str
    request: dict[str, Any]
    result: dict[str, Any] | None
    error: str | None
    created_at: str
    started_at: str | None
    finished_at: str | None
    attempts: int
    lease_until: float | None
    cancel_requested: bool
    batch_id: str | None


@dataclass(frozen=True)
class StaleJob:
    """A queued job whose hand-over to the queue may have been lost (ages in seconds)."""

    id: str
    attempts: int
    created_ago: float
    published_ago: float | None  # None: never published


@dataclass(frozen=True)
class BatchRecord:
    """Jobs submitted together; ``idempotency_key`` makes a retried submission a no-op."""

    id: str
    owner: str
    idempotency_key: str | None
    request_hash: str
    job_ids: list[str] = field(default_factory=list)
    created_at: str = ""


@dataclass(frozen=True)
class Claim:
    """Outcome of :meth:`Store.claim`: run now, retry later, or nothing to do."""

    run: bool
    attempt: int = 0
    retry_after: float | None = None
    reason: str = ""


class IdempotencyConflictError(ValueError):
    """An Idempotency-Key was reused with a different request body."""


def _job(row: sqlite3.Row) -> JobRecord:
    return JobRecord(
        seq=row["seq"], id=row["id"], owner=row["owner"], kind=row["kind"],
        state=JobState(row["state"]), progress=row["progress"], message=row["message"],
        request=json.loads(row["request"]),
        result=json.loads(row["result"]) if row["result"] else None, error=row["error"],
        created_at=row["created_at"], started_at=row["started_at"],
        finished_at=row["finished_at"], attempts=row["attempts"],
        lease_until=row["lease_until"], cancel_requested=bool(row["cancel_requested"]),
        batch_id=row["batch_id"],
    )


_DATASETS = ("SELECT d.*, d.rowid AS seq, b.summary, b.size FROM datasets d "
             "JOIN blobs b ON b.digest = d.digest")


def _dataset(row: sqlite3.Row) -> DatasetRecord:
    return DatasetRecord(
        id=row["id"], owner=row["owner"], digest=row["digest"], name=row["name"],
        created_at=row["created_at"], summary=json.loads(row["summary"]),
        size_bytes=row["size"], source_job=row["source_job"], seq=row["seq"],
    )


def measurement_digest(measurement: Measurement) -> str:
    """SHA-256 of a measurement's content (arrays, rate, names, periods, quantity, units)."""
    h = hashlib.sha256()
    meta = [measurement.fs, measurement.input_names, measurement.output_names,
            measurement.periods, measurement.quantity, measurement.u.shape, measurement.y.shape,
            measurement.input_units, measurement.output_units]
    h.update(json.dumps(meta).encode())
    for array in (measurement.u, measurement.y):  # copies only a non-contiguous selection
        h.update(memoryview(np.ascontiguousarray(array)).cast("B"))
    return h.hexdigest()


def _owned_digest(owner: str, digest: str) -> str:
    """Address of a blob or an upload of ``owner`` (see the module docstring)."""
    return hashlib.sha256(f"{owner}|{digest}".encode()).hexdigest()


class Store:
    """File and SQLite store rooted at ``data_dir`` (created if missing).

    Parameters
    ----------
    data_dir : Path
        Root directory, shared by the API and the workers.
    """

    def __init__(self, data_dir: Path) -> None:
        self.root = Path(data_dir).resolve()
        self.blobs = self.root / "blobs"
        self.jobs_dir = self.root / "jobs"
        self.tmp = self.root / "tmp"
        for d in (self.root, self.blobs, self.jobs_dir, self.tmp):
            d.mkdir(parents=True, exist_ok=True)
        self.db_path = self.root / "fnsi.sqlite3"
        self._render_locks = [threading.Lock() for _ in range(_RENDER_LOCKS)]
        with self._connect() as db:
            db.execute("PRAGMA journal_mode=WAL")
            db.executescript(_SCHEMA)

    @functools.cached_property
    def instance_id(self) -> str:
        """Random id of this store, made on first use (file ``store-id``): tells apart two
        data directories, e.g. a worker started with another FNSI_DATA_DIR than its API."""
        path = self.root / "store-id"
        if not path.exists():
            with self.partial_file() as partial:
                partial.write_text(new_id("store"))
                with suppress(FileExistsError):  # a concurrent first use won
                    os.link(partial, path)  # atomic: never a half-written id
        return path.read_text()

    @contextmanager
    def _connect(self) -> Iterator[sqlite3.Connection]:
        db = sqlite3.connect(self.db_path, timeout=30.0, isolation_level=None)
        db.row_factory = sqlite3.Row
        try:
            yield db
        finally:
            db.close()

    @contextmanager
    def _transaction(self) -> Iterator[sqlite3.Connection]:
        """Write transaction holding the database lock from the start (no lost updates)."""
        with self._connect() as db:
            db.execute("BEGIN IMMEDIATE")
            try:
                yield db
            except BaseException:
                db.execute("ROLLBACK")
                raise
            db.execute("COMMIT")

    def temp_path(self, suffix: str = "") -> Path:
        """A fresh path in the store's tmp folder (same file system as the data)."""
        fd, name = tempfile.mkstemp(dir=self.tmp, suffix=suffix)
        os.close(fd)
        return Path(name)

    @contextmanager
    def partial_file(self, suffix: str = "") -> Iterator[Path]:
        """A temp path removed if the block fails (e.g. disk full) or leaves it behind."""
        path = self.temp_path(suffix)
        try:
            yield path
        finally:
            path.unlink(missing_ok=True)

    # -- datasets ---------------------------------------------------------------------------
    def blob_path(self, digest: str) -> Path:
        """Canonical NPZ file of a dataset blob."""
        return self.blobs / f"{digest}.npz"

    def dataset_for_upload(self, upload_key: str, owner: str, name: str) -> DatasetRecord | None:
        """New dataset sharing the blob of an identical earlier upload of ``owner``, if
        there was one."""
        with self._transaction() as db:
            row = db.execute("SELECT digest FROM uploads WHERE upload_key = ?",
                             (_owned_digest(owner, upload_key),)).fetchone()
            if row is None:
                return None
            return self._insert_dataset(db, owner, row["digest"], name, None)

    def put_measurement(self, measurement: Measurement, *, owner: str, name: str,
                        periods_source: str = "declared", upload_key: str | None = None,
                        source_job: str | None = None) -> DatasetRecord:
        """Store a validated measurement as a new dataset of ``owner``.

        The canonical NPZ is written once per owner and distinct content; identical
        content of one owner shares it.
        """
        if source_job is not None:  # a re-run attempt must not add a second dataset
            earlier = self.dataset_of_job(source_job)
            if earlier is not None:
                return earlier
        digest = _owned_digest(owner, measurement_digest(measurement))
        path = self.blob_path(digest)
        summary = summarize(measurement, periods_source)
        with self.partial_file(".npz") as partial:
            # Written before taking the lock (slow); a file left by an interrupted write or
            # by a concurrent identical upload is simply replaced.
            with open(partial, "wb") as f:
                measurement.to_npz(f)
            with self._transaction() as db:
                known = db.execute("SELECT 1 FROM blobs WHERE digest = ?", (digest,)).fetchone()
                if known is None:
                    os.replace(partial, path)
                    db.execute("INSERT INTO blobs (digest, summary, size) VALUES (?, ?, ?)",
                               (digest, json.dumps(summary), path.stat().st_size))
                if upload_key is not None:
                    db.execute("INSERT OR REPLACE INTO uploads (upload_key, digest) "
                               "VALUES (?, ?)", (_owned_digest(owner, upload_key), digest))
                return self._insert_dataset(db, owner, digest, name, source_job)

    def _insert_dataset(self, db: sqlite3.Connection, owner: str, digest: str, name: str,
                        source_job: str | None) -> DatasetRecord:
        dataset_id = new_id("ds")
        db.execute("INSERT INTO datasets (id, owner, digest, name, source_job, created_at) "
                   "VALUES (?, ?, ?, ?, ?, ?)",
                   (dataset_id, owner, digest, name, source_job, now_iso()))
        return self._dataset_row(db, dataset_id)

    @staticmethod
    def _dataset_row(db: sqlite3.Connection, dataset_id: str) -> DatasetRecord | None:
        row = db.execute(f"{_DATASETS} WHERE d.id = ?", (dataset_id,)).fetchone()
        return None if row is None else _dataset(row)

    def list_datasets(self, owner: str, *, before_seq: int | None = None,
                      limit: int = 50) -> list[DatasetRecord]:
        """Datasets of ``owner``, newest first; ``before_seq`` pages."""
        sql, args = f"{_DATASETS} WHERE d.owner = ?", [owner]
        if before_seq is not None:
            sql += " AND d.rowid < ?"
            args.append(before_seq)
        with self._connect() as db:
            rows = db.execute(f"{sql} ORDER BY d.rowid DESC LIMIT ?", [*args, limit])
            return [_dataset(r) for r in rows.fetchall()]

    def dataset_of_job(self, job_id: str) -> DatasetRecord | None:
        """Dataset produced by a simulation job, if it stored one."""
        with self._connect() as db:
            row = db.execute("SELECT id FROM datasets WHERE source_job = ?", (job_id,)).fetchone()
            return None if row is None else self._dataset_row(db, row["id"])

    def get_dataset(self, dataset_id: str) -> DatasetRecord | None:
        """Dataset record, or None if unknown."""
        with self._connect() as db:
            return self._dataset_row(db, dataset_id)

    def load_measurement(self, dataset_id: str) -> Measurement:
        """The measurement of a dataset; ValueError if it no longer exists."""
        record = self.get_dataset(dataset_id)
        if record is None:
            raise ValueError(f"dataset {dataset_id} does not exist (deleted?); upload it again")
        return Measurement.from_npz(self.blob_path(record.digest))

    def delete_dataset(self, dataset_id: str) -> None:
        """Remove a dataset; its blob goes when no other dataset shares it."""
        with self._transaction() as db:
            row = db.execute("SELECT digest FROM datasets WHERE id = ?", (dataset_id,)).fetchone()
            if row is None:
                return
            digest = row["digest"]
            db.execute("DELETE FROM datasets WHERE id = ?", (dataset_id,))
            shared = db.execute("SELECT 1 FROM datasets WHERE digest = ? LIMIT 1",
                                (digest,)).fetchone()
            if shared is None:
                db.execute("DELETE FROM uploads WHERE digest = ?", (digest,))
                db.execute("DELETE FROM blobs WHERE digest = ?", (digest,))
                # Inside the lock, so a concurrent identical upload cannot lose its file.
                self.blob_path(digest).unlink(missing_ok=True)
                self.blob_path(digest).with_suffix(".csv").unlink(missing_ok=True)

    def open_blob(self, record: DatasetRecord) -> BinaryIO | None:
        """The dataset's canonical NPZ opened for reading; None once it is deleted.

        An open file stays whole if the dataset is deleted while it is read (unlink
        removes the name, not the data), so a download is complete or never starts.
        """
        with suppress(FileNotFoundError):
            return open(self.blob_path(record.digest), "rb")
        return None

    def open_csv(self, record: DatasetRecord) -> BinaryIO | None:
        """The dataset's CSV rendering opened for reading; None once it is deleted.

        Rendered on first request, once (concurrent requests for one blob wait for it),
        kept beside the blob and deleted with it. ValueError if the dataset has several
        realisations (CSV holds one).
        """
        path = self.blob_path(record.digest).with_suffix(".csv")
        with suppress(FileNotFoundError):
            return open(path, "rb")
        with self._render_locks[int(record.digest[:8], 16) % _RENDER_LOCKS]:
            with suppress(FileNotFoundError):
                return open(path, "rb")  # rendered while we waited
            return self._render_csv(record, path)

    def _render_csv(self, record: DatasetRecord, path: Path) -> BinaryIO | None:
        blob = self.open_blob(record)
        if blob is None:
            return None
        with blob:
            measurement = Measurement.from_npz(blob)
        with self.partial_file(".csv") as partial:
            with open(partial, "w") as f:  # slow: outside the database lock
                measurement.to_csv(f)
            with self._transaction() as db:
                # Put in place only if the blob still exists (delete_dataset removes the
                # rendering in this lock), and opened before the lock is released.
                if db.execute("SELECT 1 FROM blobs WHERE digest = ?",
                              (record.digest,)).fetchone():
                    os.replace(partial, path)
                    return open(path, "rb")
        return None

    # -- jobs -------------------------------------------------------------------------------
    def create_job(self, owner: str, kind: str, request: dict[str, Any]) -> JobRecord:
        """Record a queued job."""
        with self._transaction() as db:
            job_id = self._insert_job(db, owner, kind, request, None)
            return self._job_row(db, job_id)

    @staticmethod
    def _insert_job(db: sqlite3.Connection, owner: str, kind: str, request: dict[str, Any],
                    batch_id: str | None) -> str:
        job_id = new_id("job")
        db.execute("INSERT INTO jobs (id, owner, kind, state, message, request, created_at, "
                   "batch_id) VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                   (job_id, owner, kind, JobState.QUEUED, "waiting for a worker",
                    json.dumps(request), now_iso(), batch_id))
        return job_id

    @staticmethod
    def _job_row(db: sqlite3.Connection, job_id: str) -> JobRecord | None:
        row = db.execute("SELECT * FROM jobs WHERE id = ?", (job_id,)).fetchone()
        return None if row is None else _job(row)

    def get_job(self, job_id: str) -> JobRecord | None:
        """Job record, or None if unknown."""
        with self._connect() as db:
            return self._job_row(db, job_id)

    def list_jobs(self, owner: str, *, state: str | None = None, kind: str | None = None,
                  before_seq: int | None = None, limit: int = 50) -> list[JobRecord]:
        """Jobs of ``owner``, newest first, optionally filtered; ``before_seq`` pages."""
        sql, args = "SELECT * FROM jobs WHERE owner = ?", [owner]
        for column, value in (("state", state), ("kind", kind)):
            if value is not None:
                sql += f" AND {column} = ?"
                args.append(value)
        if before_seq is not None:
            sql += " AND seq < ?"
            args.append(before_seq)
        sql += " ORDER BY seq DESC LIMIT ?"
        args.append(limit)
        with self._connect() as db:
            return [_job(r) for r in db.execute(sql, args).fetchall()]

    def mark_enqueued(self, job_id: str) -> None:
        """Remember when a job was last handed to the queue."""
        with self._transaction() as db:
            db.execute("UPDATE jobs SET enqueued_at = ? WHERE id = ?", (time.time(), job_id))

    def stale_queued(self, older_than: float) -> list[StaleJob]:
        """Queued jobs never handed to the queue (the broker was unreachable), or last
        handed over more than ``older_than`` seconds ago (their message may be lost:
        broker restarted, or consumed by a foreign worker)."""
        now = time.time()
        with self._connect() as db:
            rows = db.execute("SELECT id, attempts, created_at, enqueued_at FROM jobs "
                              "WHERE state = ? AND (enqueued_at IS NULL OR enqueued_at < ?) "
                              "ORDER BY seq", (JobState.QUEUED, now - older_than)).fetchall()
        return [StaleJob(r["id"], r["attempts"],
                         now - datetime.fromisoformat(r["created_at"]).timestamp(),
                         None if r["enqueued_at"] is None else now - r["enqueued_at"])
                for r in rows]

    def jobs_in_state(self, state: JobState) -> list[JobRecord]:
        """Every job in ``state``, oldest first (used to resume after a restart)."""
        with self._connect() as db:
            rows = db.execute("SELECT * FROM jobs WHERE state = ? ORDER BY seq", (state,))
            return [_job(r) for r in rows.fetchall()]

    def claim(self, job_id: str, *, lease_seconds: float, max_attempts: int) -> Claim:
        """Atomically start an attempt of a job, so that a redelivered task runs at most once.

        A job runs when it is queued, or running with an expired lease (its worker died).
        A running job whose lease is alive belongs to another worker: retry after the lease.
        """
        now = time.time()
        with self._transaction() as db:
            job = self._job_row(db, job_id)
            if job is None:
                return Claim(False, reason="unknown job")
            if job.state in TERMINAL:
                return Claim(False, reason=f"already {job.state}")
            if job.state == JobState.RUNNING and (job.lease_until or 0) > now:
                return Claim(False, retry_after=job.lease_until - now, reason="running elsewhere")
            if job.cancel_requested:
                self._finish(db, job_id, JobState.CANCELLED, message="cancelled before start")
                return Claim(False, reason="cancelled")
            if job.attempts >= max_attempts:
                self._finish(db, job_id, JobState.FAILED, error=_lost_reason(job.attempts))
                return Claim(False, reason="attempts exhausted")
            db.execute("UPDATE jobs SET state = ?, attempts = attempts + 1, lease_until = ?, "
                       "started_at = ?, progress = 0, message = ? WHERE id = ?",
                       (JobState.RUNNING, now + lease_seconds, now_iso(),
                        f"started (attempt {job.attempts + 1})", job_id))
            return Claim(True, attempt=job.attempts + 1)

    def report(self, job_id: str, *, lease_seconds: float, progress: float | None = None,
               message: str | None = None) -> bool:
        """Renew the lease of a running job, optionally with progress; True if cancel asked."""
        with self._transaction() as db:
            db.execute("UPDATE jobs SET lease_until = ?, progress = COALESCE(?, progress), "
                       "message = COALESCE(?, message) WHERE id = ? AND state = ?",
                       (time.time() + lease_seconds, progress, message, job_id,
                        JobState.RUNNING))
            row = db.execute("SELECT cancel_requested FROM jobs WHERE id = ?",
                             (job_id,)).fetchone()
            return bool(row and row["cancel_requested"])

    def finish(self, job_id: str, state: JobState, *, result: dict | None = None,
               error: str | None = None, message: str = "") -> None:
        """End a running job (terminal state, result or error)."""
        with self._transaction() as db:
            self._finish(db, job_id, state, result=result, error=error, message=message)

    @staticmethod
    def _finish(db: sqlite3.Connection, job_id: str, state: JobState, *, result=None,
                error=None, message: str = "") -> None:
        progress = 1.0 if state == JobState.SUCCEEDED else None
        db.execute("UPDATE jobs SET state = ?, result = ?, error = ?, finished_at = ?, "
                   "lease_until = NULL, progress = COALESCE(?, progress), message = ? "
                   "WHERE id = ?",
                   (state, json.dumps(result) if result is not None else None, error,
                    now_iso(), progress, message or state.value, job_id))

    def request_cancel(self, job_id: str) -> JobRecord:
        """Cancel a queued job at once; flag a running one (its task stops at next report)."""
        with self._transaction() as db:
            job = self._job_row(db, job_id)
            if job.state == JobState.QUEUED:
                self._finish(db, job_id, JobState.CANCELLED, message="cancelled before start")
            elif job.state == JobState.RUNNING:
                db.execute("UPDATE jobs SET cancel_requested = 1, message = ? WHERE id = ?",
                           ("cancellation requested", job_id))
            return self._job_row(db, job_id)

    def delete_job(self, job_id: str) -> bool:
        """Delete a finished job with its artefacts; False if it is not finished (or gone)."""
        return bool(self._delete_finished("id = ?", (job_id,)))

    def delete_jobs_finished_before(self, time_iso: str, keep_kinds: tuple[str, ...]
                                    ) -> list[str]:
        """Delete the jobs finished before ``time_iso`` (ISO 8601 UTC) with their artefacts,
        except those of ``keep_kinds``; their ids."""
        marks = ", ".join("?" * len(keep_kinds))
        return self._delete_finished(f"finished_at < ? AND kind NOT IN ({marks})",
                                     (time_iso, *keep_kinds))

    def _delete_finished(self, condition: str, args: tuple[Any, ...]) -> list[str]:
        """Delete the finished jobs matching an SQL ``condition``; their ids.

        Artefact folders are moved to tmp/ inside the lock, with the records, and removed
        after it: no listing ever sees a job without its folder or a folder without its
        job, and a crash leaves only scratch files behind.
        """
        removed, doomed = [], []
        with self._transaction() as db:
            states = ", ".join("?" * len(TERMINAL))
            rows = db.execute(f"SELECT id FROM jobs WHERE state IN ({states}) AND {condition}",
                              (*TERMINAL, *args)).fetchall()
            for row in rows:
                db.execute("DELETE FROM jobs WHERE id = ?", (row["id"],))
                removed.append(row["id"])
                folder = self.artefact_dir(row["id"])
                if folder.is_dir():
                    doomed.append(Path(tempfile.mkdtemp(dir=self.tmp)) / row["id"])
                    os.replace(folder, doomed[-1])
        for folder in doomed:
            shutil.rmtree(folder.parent, ignore_errors=True)
        return removed

    def reap_lost(self, max_attempts: int) -> list[str]:
        """Re-queue (or fail, after ``max_attempts``) running jobs whose lease expired.

        Returns
        -------
        list of str
            Ids of the re-queued jobs, to be handed to the queue again.
        """
        requeued = []
        with self._transaction() as db:
            rows = db.execute("SELECT * FROM jobs WHERE state = ? AND lease_until < ?",
                              (JobState.RUNNING, time.time())).fetchall()
            for job in map(_job, rows):
                if job.cancel_requested:
                    self._finish(db, job.id, JobState.CANCELLED, message="cancelled")
                elif job.attempts >= max_attempts:
                    self._finish(db, job.id, JobState.FAILED, error=_lost_reason(job.attempts))
                else:
                    db.execute("UPDATE jobs SET state = ?, lease_until = NULL, progress = 0, "
                               "message = ? WHERE id = ?",
                               (JobState.QUEUED, f"re-queued: its worker stopped during "
                                f"attempt {job.attempts} of {max_attempts}", job.id))
                    requeued.append(job.id)
        return requeued

    # -- batches ----------------------------------------------------------------------------
    def create_batch(self, owner: str, jobs: list[tuple[str, dict[str, Any]]], *,
                     idempotency_key: str | None) -> tuple[BatchRecord, bool]:
        """Record a batch and its queued jobs in one transaction.

        Returns
        -------
        (BatchRecord, bool)
            The batch and whether it was created now (False: the first answer to a retried
            request with the same Idempotency-Key).

        Raises
        ------
        IdempotencyConflictError
            The key was used before with a different request.
        """
        request_hash = hashlib.sha256(json.dumps(jobs, sort_keys=True).encode()).hexdigest()
        with self._transaction() as db:
            if idempotency_key is not None:
                row = db.execute("SELECT * FROM batches WHERE owner = ? AND idempotency_key = ?",
                                 (owner, idempotency_key)).fetchone()
                if row is not None:
                    if row["request_hash"] != request_hash:
                        raise IdempotencyConflictError(
                            "this Idempotency-Key was already used for a different batch; "
                            "use a new key for a new request")
                    return _batch(row), False
            batch_id = new_id("batch")
            job_ids = [self._insert_job(db, owner, kind, req, batch_id) for kind, req in jobs]
            db.execute("INSERT INTO batches (id, owner, idempotency_key, request_hash, job_ids, "
                       "created_at) VALUES (?, ?, ?, ?, ?, ?)",
                       (batch_id, owner, idempotency_key, request_hash, json.dumps(job_ids),
                        now_iso()))
            row = db.execute("SELECT * FROM batches WHERE id = ?", (batch_id,)).fetchone()
            return _batch(row), True

    def get_batch(self, batch_id: str) -> BatchRecord | None:
        """Batch record, or None if unknown."""
        with self._connect() as db:
            row = db.execute("SELECT * FROM batches WHERE id = ?", (batch_id,)).fetchone()
            return None if row is None else _batch(row)

    def jobs_of(self, job_ids: list[str]) -> list[JobRecord]:
        """Job records in the order of ``job_ids`` (deleted jobs left out)."""
        with self._connect() as db:
            return [job for j in job_ids if (job := self._job_row(db, j)) is not None]

    # -- artefacts --------------------------------------------------------------------------
    def artefact_dir(self, job_id: str) -> Path:
        """Folder of a job's artefacts."""
        return self.jobs_dir / job_id

    def write_artefact(self, job_id: str, name: str, data: bytes) -> None:
        """Write one artefact atomically (a re-run attempt overwrites it whole)."""
        if not ARTEFACT_NAME.match(name):
            raise ValueError(f"invalid artefact name {name!r}")
        folder = self.artefact_dir(job_id)
        folder.mkdir(parents=True, exist_ok=True)
        with self.partial_file() as partial:
            partial.write_bytes(data)
            os.replace(partial, folder / name)

    def list_artefacts(self, job_id: str) -> list[tuple[str, int]]:
        """(name, size in bytes) of every artefact of a job, sorted by name."""
        folder = self.artefact_dir(job_id)
        if not folder.is_dir():
            return []
        return sorted((p.name, p.stat().st_size) for p in folder.iterdir()
                      if p.is_file() and ARTEFACT_NAME.match(p.name))

    def artefact_path(self, job_id: str, name: str) -> Path | None:
        """Path of an artefact found by listing (a name is never used as a path)."""
        listed = {n for n, _ in self.list_artefacts(job_id)}
        return self.artefact_dir(job_id) / name if name in listed else None

    def open_artefact(self, job_id: str, name: str) -> BinaryIO | None:
        """An artefact found by listing, opened for reading; None if the job has no such
        artefact, or no longer (deleted with its job)."""
        path = self.artefact_path(job_id, name)
        if path is not None:
            with suppress(FileNotFoundError):
                return open(path, "rb")
        return None


def _batch(row: sqlite3.Row) -> BatchRecord:
    return BatchRecord(id=row["id"], owner=row["owner"], idempotency_key=row["idempotency_key"],
                       request_hash=row["request_hash"], job_ids=json.loads(row["job_ids"]),
                       created_at=row["created_at"])


def _lost_reason(attempts: int) -> str:
    return (f"the worker running this job stopped (killed, crashed or out of memory) on each "
            f"of {attempts} attempts; check the worker logs, give the worker more memory or "
            "submit a smaller problem")
