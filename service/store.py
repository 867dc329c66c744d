"""Persistent store of datasets, job records, batches and artefacts under FNSI_DATA_DIR.

The store is the single source of truth for job state: the API, the embedded runner and
Celery workers all read and write it, never the broker's result backend. Records live in
a database (:mod:`service.database`): SQLite in the data directory (atomic transactions,
safe across processes on one host), or PostgreSQL (FNSI_DATABASE_URL) shared by API and
worker processes on many hosts. Dataset arrays live in content-addressed canonical NPZ
files, artefacts in one folder per job; with FNSI_BLOB_STORE=database these files are
also shared objects in PostgreSQL (:mod:`service.objects`), written in the transaction of
the record that names them, and the data directory of each host is only their cache.

Blobs and the upload cache are addressed by owner and content together: identical uploads
of one API key share a blob, those of two keys never do, so an upload takes the same path
and time whatever another key holds (a shared cache would tell a key, by its speed,
whether another holds a given file).

Layout::

    <data_dir>/fnsi.sqlite3          records (without FNSI_DATABASE_URL)
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
import tempfile
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from datetime import UTC, datetime
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Any, BinaryIO

import numpy as np
from sqlalchemy import ColumnElement, Connection, RowMapping, delete, insert, select, update
from sqlalchemy.dialects import postgresql, sqlite

from fnsi.measurement import Measurement
from fnsi.summary import summarize
from service.database import Database, sqlite_url
from service.objects import DatabaseObjects
from service.schema import STUDY_JOB_KINDS, batches, blobs, datasets, jobs, store_info, uploads

if TYPE_CHECKING:
    from service.settings import Settings

ARTEFACT_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,99}$")
# CSV renderings run one at a time per lock; a blob always takes the same lock.
_RENDER_LOCKS = 16

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


class LeaseLostError(RuntimeError):
    """An attempt no longer holds its job: its lease lapsed (e.g. the database was out of
    reach for longer than the lease) and the job was re-queued or ended. The attempt must
    stop and store nothing, so that at most one attempt of a job completes."""

    def __init__(self, job_id: str, attempt: int) -> None:
        super().__init__(f"job {job_id}: attempt {attempt} lost its lease")


def _running(job_id: str, attempt: int | None) -> ColumnElement[bool]:
    """The job is running (``attempt``: that attempt)."""
    condition = (jobs.c.id == job_id) & (jobs.c.state == JobState.RUNNING.value)
    return condition if attempt is None else condition & (jobs.c.attempts == attempt)


def _job(row: RowMapping) -> JobRecord:
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


_DATASETS = select(datasets, blobs.c.summary, blobs.c.size).join_from(
    datasets, blobs, datasets.c.digest == blobs.c.digest)


def _dataset(row: RowMapping) -> DatasetRecord:
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
    """File and database store rooted at ``data_dir`` (created if missing).

    Parameters
    ----------
    data_dir : Path
        Root directory of the files, shared by the API and the workers.
    database_url : str, optional
        Database of the records (``postgresql://...``); default: SQLite in ``data_dir``.
    blob_store : {"folder", "database"}
        Where blobs and artefacts are kept: only in ``data_dir`` (hosts share it), or also
        in the PostgreSQL database, ``data_dir`` being this host's cache
        (:mod:`service.objects`).
    """

    def __init__(self, data_dir: Path, database_url: str | None = None,
                 blob_store: str = "folder") -> None:
        self.root = Path(data_dir).resolve()
        self.blobs = self.root / "blobs"
        self.jobs_dir = self.root / "jobs"
        self.tmp = self.root / "tmp"
        for d in (self.root, self.blobs, self.jobs_dir, self.tmp):
            d.mkdir(parents=True, exist_ok=True)
        self.db_path = self.root / "fnsi.sqlite3"
        self.db = Database(database_url or sqlite_url(self.db_path))
        if blob_store == "database" and not self.db.shared:
            raise ValueError("FNSI_BLOB_STORE=database keeps blobs in the PostgreSQL database: "
                             "set FNSI_DATABASE_URL=postgresql://... as well")
        self.objects = DatabaseObjects() if blob_store == "database" else None
        self._render_locks = [threading.Lock() for _ in range(_RENDER_LOCKS)]

    @classmethod
    def from_settings(cls, settings: Settings) -> Store:
        """The store of :class:`service.settings.Settings` (data dir, database, blobs)."""
        return cls(settings.data_dir, settings.database_url, settings.blob_store)

    @functools.cached_property
    def instance_id(self) -> str:
        """Random id of this store's records, made on first use: tells apart two stores,
        e.g. a worker started with another FNSI_DATABASE_URL (or, on SQLite, another
        FNSI_DATA_DIR) than its API. A store made before the id moved into the database
        keeps the id of its file ``store-id``."""
        legacy = self.root / "store-id"
        with self.db.transaction() as db:
            self.db.lock_key(db, "store-id")
            found = db.execute(select(store_info.c.value).where(store_info.c.key == "id"))
            value = found.scalar()
            if value is None:
                value = legacy.read_text() if legacy.is_file() and not self.db.shared else (
                    new_id("store"))
                db.execute(insert(store_info).values(key="id", value=value))
        return value

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

    # -- shared objects (FNSI_BLOB_STORE=database) -------------------------------------------
    def _key(self, path: Path) -> str:
        """Object key of a file of the data directory: its relative path."""
        return path.relative_to(self.root).as_posix()

    def _share(self, db: Connection, path: Path, source: Path | None = None) -> None:
        """Copy the file ``path`` (read from ``source`` if given) into the shared objects,
        in the transaction of ``db``."""
        if self.objects is not None:
            self.objects.put(db, self._key(path), source or path)

    def share_file(self, path: Path, source: Path) -> None:
        """Share the file ``source`` as the file ``path`` of the data directory (no-op
        without shared objects)."""
        if self.objects is not None:
            with self.db.transaction() as db:
                self._share(db, path, source)

    def share_folder(self, folder: Path, source: Path) -> None:
        """Share every file of the folder ``source`` as the files of the new folder
        ``folder`` of the data directory, all or none (no-op without shared objects).

        Raises
        ------
        FileExistsError
            ``folder`` is shared already (as renaming onto a full folder would).
        """
        if self.objects is None:
            return
        prefix = f"{self._key(folder)}/"
        with self.db.transaction() as db:
            self.db.lock_key(db, prefix)
            if self.objects.listing(db, prefix):
                raise FileExistsError(f"{self._key(folder)} exists already")
            for file in sorted(source.iterdir()):
                self._share(db, folder / file.name, file)

    def unshare_folder(self, folder: Path) -> None:
        """Remove the shared objects of the files of ``folder`` (no-op without them)."""
        if self.objects is not None:
            with self.db.transaction() as db:
                self.objects.delete_under(db, f"{self._key(folder)}/")

    def shared_files(self, folder: Path) -> list[str] | None:
        """Relative paths of the shared files under ``folder``; None without shared
        objects (the data directory is then the only copy)."""
        if self.objects is None:
            return None
        with self.db.read() as db:
            return [name for name, _ in self.objects.listing(db, f"{self._key(folder)}/")]

    def _fetch(self, path: Path) -> None:
        """Put the shared object of ``path`` in place in this host's data directory."""
        path.parent.mkdir(parents=True, exist_ok=True)
        with self.partial_file(path.suffix) as partial, self.db.read() as db:
            if self.objects.fetch(db, self._key(path), partial):
                os.replace(partial, path)

    def cached(self, path: Path) -> Path:
        """``path`` of an immutable file, fetched first if this host does not have it."""
        if self.objects is not None and not path.exists():
            self._fetch(path)
        return path

    # -- datasets ---------------------------------------------------------------------------
    def blob_path(self, digest: str) -> Path:
        """Canonical NPZ file of a dataset blob."""
        return self.blobs / f"{digest}.npz"

    def dataset_for_upload(self, upload_key: str, owner: str, name: str) -> DatasetRecord | None:
        """New dataset sharing the blob of an identical earlier upload of ``owner``, if
        there was one."""
        key = _owned_digest(owner, upload_key)
        with self.db.transaction() as db:
            digest = db.execute(select(uploads.c.digest).where(uploads.c.upload_key == key)
                                ).scalar()
            if digest is None:
                return None
            self.db.lock_key(db, f"blob:{digest}")  # against delete_dataset of its last user
            if db.execute(select(uploads.c.digest).where(uploads.c.upload_key == key)
                          ).scalar() is None:
                return None
            return self._insert_dataset(db, owner, digest, name, None)

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
            with self.db.transaction() as db:
                self.db.lock_key(db, f"blob:{digest}")
                if not self._blob_known(db, digest):
                    os.replace(partial, path)
                    self._share(db, path)
                    db.execute(insert(blobs).values(digest=digest, summary=json.dumps(summary),
                                                    size=path.stat().st_size))
                if upload_key is not None:
                    self._remember_upload(db, _owned_digest(owner, upload_key), digest)
                return self._insert_dataset(db, owner, digest, name, source_job)

    @staticmethod
    def _blob_known(db: Connection, digest: str) -> bool:
        return db.execute(select(blobs.c.digest).where(blobs.c.digest == digest)
                          ).first() is not None

    @staticmethod
    def _remember_upload(db: Connection, upload_key: str, digest: str) -> None:
        """Point ``upload_key`` at ``digest`` (insert, or replace an earlier answer)."""
        dialect = postgresql if db.dialect.name == "postgresql" else sqlite
        statement = dialect.insert(uploads).values(upload_key=upload_key, digest=digest)
        db.execute(statement.on_conflict_do_update(index_elements=[uploads.c.upload_key],
                                                   set_={"digest": digest}))

    def _insert_dataset(self, db: Connection, owner: str, digest: str, name: str,
                        source_job: str | None) -> DatasetRecord:
        dataset_id = new_id("ds")
        db.execute(insert(datasets).values(id=dataset_id, owner=owner, digest=digest, name=name,
                                           source_job=source_job, created_at=now_iso()))
        return self._dataset_row(db, dataset_id)

    @staticmethod
    def _dataset_row(db: Connection, dataset_id: str) -> DatasetRecord | None:
        row = db.execute(_DATASETS.where(datasets.c.id == dataset_id)).mappings().first()
        return None if row is None else _dataset(row)

    def list_datasets(self, owner: str, *, before_seq: int | None = None,
                      limit: int = 50) -> list[DatasetRecord]:
        """Datasets of ``owner``, newest first; ``before_seq`` pages."""
        query = _DATASETS.where(datasets.c.owner == owner)
        if before_seq is not None:
            query = query.where(datasets.c.seq < before_seq)
        with self.db.read() as db:
            rows = db.execute(query.order_by(datasets.c.seq.desc()).limit(limit)).mappings()
            return [_dataset(r) for r in rows]

    def dataset_of_job(self, job_id: str) -> DatasetRecord | None:
        """Dataset produced by a simulation job, if it stored one."""
        with self.db.read() as db:
            row = db.execute(_DATASETS.where(datasets.c.source_job == job_id)).mappings().first()
            return None if row is None else _dataset(row)

    def get_dataset(self, dataset_id: str) -> DatasetRecord | None:
        """Dataset record, or None if unknown."""
        with self.db.read() as db:
            return self._dataset_row(db, dataset_id)

    def load_measurement(self, dataset_id: str) -> Measurement:
        """The measurement of a dataset; ValueError if it no longer exists."""
        record = self.get_dataset(dataset_id)
        if record is None:
            raise ValueError(f"dataset {dataset_id} does not exist (deleted?); upload it again")
        return Measurement.from_npz(self.cached(self.blob_path(record.digest)))

    def delete_dataset(self, dataset_id: str) -> None:
        """Remove a dataset; its blob goes when no other dataset shares it."""
        with self.db.transaction() as db:
            digest = db.execute(select(datasets.c.digest).where(datasets.c.id == dataset_id)
                                ).scalar()
            if digest is None:
                return
            self.db.lock_key(db, f"blob:{digest}")
            if not db.execute(delete(datasets).where(datasets.c.id == dataset_id)).rowcount:
                return  # deleted meanwhile by another request
            shared = db.execute(select(datasets.c.id).where(datasets.c.digest == digest)
                                .limit(1)).first()
            if shared is None:
                db.execute(delete(uploads).where(uploads.c.digest == digest))
                db.execute(delete(blobs).where(blobs.c.digest == digest))
                if self.objects is not None:
                    self.objects.delete(db, [self._key(self.blob_path(digest))])
                # Inside the lock, so a concurrent identical upload cannot lose its file.
                self.blob_path(digest).unlink(missing_ok=True)
                self.blob_path(digest).with_suffix(".csv").unlink(missing_ok=True)

    def open_blob(self, record: DatasetRecord) -> BinaryIO | None:
        """The dataset's canonical NPZ opened for reading; None once it is deleted.

        An open file stays whole if the dataset is deleted while it is read (unlink
        removes the name, not the data), so a download is complete or never starts.
        """
        with suppress(FileNotFoundError):
            return open(self.cached(self.blob_path(record.digest)), "rb")
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
            with self.db.transaction() as db:
                # Put in place only if the blob still exists (delete_dataset removes the
                # rendering in this lock), and opened before the lock is released.
                self.db.lock_key(db, f"blob:{record.digest}")
                if self._blob_known(db, record.digest):
                    os.replace(partial, path)
                    return open(path, "rb")
        return None

    # -- jobs -------------------------------------------------------------------------------
    def create_job(self, owner: str, kind: str, request: dict[str, Any]) -> JobRecord:
        """Record a queued job."""
        with self.db.transaction() as db:
            job_id = self._insert_job(db, owner, kind, request, None)
            return self._job_row(db, job_id)

    @staticmethod
    def _insert_job(db: Connection, owner: str, kind: str, request: dict[str, Any],
                    batch_id: str | None) -> str:
        job_id = new_id("job")
        study_id = request.get("study_id") if kind in STUDY_JOB_KINDS else None
        db.execute(insert(jobs).values(
            id=job_id, owner=owner, kind=kind, state=JobState.QUEUED.value,
            message="waiting for a worker", request=json.dumps(request), created_at=now_iso(),
            batch_id=batch_id, study_id=study_id))
        return job_id

    @staticmethod
    def _job_row(db: Connection, job_id: str, *, lock: bool = False) -> JobRecord | None:
        """The job; ``lock``: row-locked to the end of the transaction (PostgreSQL)."""
        query = select(jobs).where(jobs.c.id == job_id)
        row = db.execute(query.with_for_update() if lock else query).mappings().first()
        return None if row is None else _job(row)

    def get_job(self, job_id: str) -> JobRecord | None:
        """Job record, or None if unknown."""
        with self.db.read() as db:
            return self._job_row(db, job_id)

    def list_jobs(self, owner: str, *, state: str | None = None, kind: str | None = None,
                  before_seq: int | None = None, limit: int = 50) -> list[JobRecord]:
        """Jobs of ``owner``, newest first, optionally filtered; ``before_seq`` pages."""
        query = select(jobs).where(jobs.c.owner == owner)
        for column, value in ((jobs.c.state, state), (jobs.c.kind, kind)):
            if value is not None:
                query = query.where(column == value)
        if before_seq is not None:
            query = query.where(jobs.c.seq < before_seq)
        with self.db.read() as db:
            rows = db.execute(query.order_by(jobs.c.seq.desc()).limit(limit)).mappings()
            return [_job(r) for r in rows]

    def jobs_of_study(self, study_id: str, owner: str) -> list[JobRecord]:
        """Every job of ``owner`` acting on the study ``study_id``, oldest first."""
        query = select(jobs).where(jobs.c.study_id == study_id, jobs.c.owner == owner)
        with self.db.read() as db:
            return [_job(r) for r in db.execute(query.order_by(jobs.c.seq)).mappings()]

    def mark_enqueued(self, job_id: str) -> None:
        """Remember when a job was last handed to the queue."""
        with self.db.transaction() as db:
            db.execute(update(jobs).where(jobs.c.id == job_id).values(enqueued_at=time.time()))

    def stale_queued(self, older_than: float) -> list[StaleJob]:
        """Queued jobs never handed to the queue (the broker was unreachable), or last
        handed over more than ``older_than`` seconds ago (their message may be lost:
        broker restarted, or consumed by a foreign worker)."""
        now = time.time()
        query = select(jobs.c.id, jobs.c.attempts, jobs.c.created_at, jobs.c.enqueued_at).where(
            jobs.c.state == JobState.QUEUED.value,
            jobs.c.enqueued_at.is_(None) | (jobs.c.enqueued_at < now - older_than))
        with self.db.read() as db:
            rows = db.execute(query.order_by(jobs.c.seq)).mappings().all()
        return [StaleJob(r["id"], r["attempts"],
                         now - datetime.fromisoformat(r["created_at"]).timestamp(),
                         None if r["enqueued_at"] is None else now - r["enqueued_at"])
                for r in rows]

    def jobs_in_state(self, state: JobState) -> list[JobRecord]:
        """Every job in ``state``, oldest first (used to resume after a restart)."""
        query = select(jobs).where(jobs.c.state == JobState(state).value).order_by(jobs.c.seq)
        with self.db.read() as db:
            return [_job(r) for r in db.execute(query).mappings()]

    def claim(self, job_id: str, *, lease_seconds: float, max_attempts: int) -> Claim:
        """Atomically start an attempt of a job, so that a redelivered task runs at most once.

        A job runs when it is queued, or running with an expired lease (its worker died).
        A running job whose lease is alive belongs to another worker: retry after the lease.
        """
        now = time.time()
        with self.db.transaction() as db:
            job = self._job_row(db, job_id, lock=True)
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
            db.execute(update(jobs).where(jobs.c.id == job_id).values(
                state=JobState.RUNNING.value, attempts=jobs.c.attempts + 1,
                lease_until=now + lease_seconds, started_at=now_iso(), progress=0.0,
                message=f"started (attempt {job.attempts + 1})"))
            return Claim(True, attempt=job.attempts + 1)

    def report(self, job_id: str, *, lease_seconds: float, progress: float | None = None,
               message: str | None = None, attempt: int | None = None) -> bool:
        """Renew the lease of a running job, optionally with progress; True if cancel asked.

        Raises
        ------
        LeaseLostError
            ``attempt`` given and the job is no longer running that attempt.
        """
        changes: dict[str, Any] = {"lease_until": time.time() + lease_seconds}
        if progress is not None:
            changes["progress"] = progress
        if message is not None:
            changes["message"] = message
        with self.db.transaction() as db:
            renewed = db.execute(update(jobs).where(_running(job_id, attempt)).values(changes))
            if attempt is not None and renewed.rowcount == 0:
                raise LeaseLostError(job_id, attempt)
            return bool(db.execute(select(jobs.c.cancel_requested).where(jobs.c.id == job_id)
                                   ).scalar())

    def finish(self, job_id: str, state: JobState, *, result: dict | None = None,
               error: str | None = None, message: str = "", attempt: int | None = None
               ) -> None:
        """End a running job (terminal state, result or error); with ``attempt``, only if
        the job still runs that attempt, else :class:`LeaseLostError`."""
        with self.db.transaction() as db:
            if attempt is not None and db.execute(
                    select(jobs.c.id).where(_running(job_id, attempt)).with_for_update()
            ).first() is None:
                raise LeaseLostError(job_id, attempt)
            self._finish(db, job_id, state, result=result, error=error, message=message)

    @staticmethod
    def _finish(db: Connection, job_id: str, state: JobState, *, result=None,
                error=None, message: str = "") -> None:
        db.execute(update(jobs).where(jobs.c.id == job_id).values(
            state=state.value, result=json.dumps(result) if result is not None else None,
            error=error, finished_at=now_iso(), lease_until=None,
            progress=1.0 if state == JobState.SUCCEEDED else jobs.c.progress,
            message=message or state.value))

    def request_cancel(self, job_id: str) -> JobRecord:
        """Cancel a queued job at once; flag a running one (its task stops at next report)."""
        with self.db.transaction() as db:
            job = self._job_row(db, job_id, lock=True)
            if job.state == JobState.QUEUED:
                self._finish(db, job_id, JobState.CANCELLED, message="cancelled before start")
            elif job.state == JobState.RUNNING:
                db.execute(update(jobs).where(jobs.c.id == job_id).values(
                    cancel_requested=True, message="cancellation requested"))
            return self._job_row(db, job_id)

    def delete_job(self, job_id: str) -> bool:
        """Delete a finished job with its artefacts; False if it is not finished (or gone)."""
        return bool(self._delete_finished(jobs.c.id == job_id))

    def delete_jobs_finished_before(self, time_iso: str, keep_kinds: tuple[str, ...]
                                    ) -> list[str]:
        """Delete the jobs finished before ``time_iso`` (ISO 8601 UTC) with their artefacts,
        except those of ``keep_kinds``; their ids."""
        return self._delete_finished((jobs.c.finished_at < time_iso)
                                     & jobs.c.kind.not_in(keep_kinds))

    def _delete_finished(self, condition: ColumnElement[bool]) -> list[str]:
        """Delete the finished jobs matching ``condition``; their ids.

        Artefact folders are moved to tmp/ inside the lock, with the records, and removed
        after it: no listing ever sees a job without its folder or a folder without its
        job, and a crash leaves only scratch files behind.
        """
        removed, doomed = [], []
        finished = [state.value for state in TERMINAL]
        with self.db.transaction() as db:
            rows = db.execute(select(jobs.c.id).where(jobs.c.state.in_(finished), condition)
                              .with_for_update(skip_locked=True)).scalars().all()
            for job_id in rows:
                db.execute(delete(jobs).where(jobs.c.id == job_id))
                if self.objects is not None:
                    self.objects.delete_under(db, f"{self._key(self.artefact_dir(job_id))}/")
                removed.append(job_id)
                folder = self.artefact_dir(job_id)
                if folder.is_dir():
                    doomed.append(Path(tempfile.mkdtemp(dir=self.tmp)) / job_id)
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
        expired = select(jobs).where(jobs.c.state == JobState.RUNNING.value,
                                     jobs.c.lease_until < time.time())
        with self.db.transaction() as db:
            rows = db.execute(expired.with_for_update(skip_locked=True)).mappings().all()
            for job in map(_job, rows):
                if job.cancel_requested:
                    self._finish(db, job.id, JobState.CANCELLED, message="cancelled")
                elif job.attempts >= max_attempts:
                    self._finish(db, job.id, JobState.FAILED, error=_lost_reason(job.attempts))
                else:
                    db.execute(update(jobs).where(jobs.c.id == job.id).values(
                        state=JobState.QUEUED.value, lease_until=None, progress=0.0,
                        message=f"re-queued: its worker stopped during attempt "
                                f"{job.attempts} of {max_attempts}"))
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
        with self.db.transaction() as db:
            if idempotency_key is not None:
                # Two concurrent retries: the second waits here, then finds the first batch.
                self.db.lock_key(db, f"batch:{owner}:{idempotency_key}")
                row = db.execute(select(batches).where(
                    batches.c.owner == owner, batches.c.idempotency_key == idempotency_key)
                ).mappings().first()
                if row is not None:
                    if row["request_hash"] != request_hash:
                        raise IdempotencyConflictError(
                            "this Idempotency-Key was already used for a different batch; "
                            "use a new key for a new request")
                    return _batch(row), False
            batch_id = new_id("batch")
            job_ids = [self._insert_job(db, owner, kind, req, batch_id) for kind, req in jobs]
            db.execute(insert(batches).values(
                id=batch_id, owner=owner, idempotency_key=idempotency_key,
                request_hash=request_hash, job_ids=json.dumps(job_ids), created_at=now_iso()))
            row = db.execute(select(batches).where(batches.c.id == batch_id)).mappings().one()
            return _batch(row), True

    def get_batch(self, batch_id: str) -> BatchRecord | None:
        """Batch record, or None if unknown."""
        with self.db.read() as db:
            row = db.execute(select(batches).where(batches.c.id == batch_id)).mappings().first()
            return None if row is None else _batch(row)

    def jobs_of(self, job_ids: list[str]) -> list[JobRecord]:
        """Job records in the order of ``job_ids`` (deleted jobs left out)."""
        with self.db.read() as db:
            found = {row["id"]: _job(row) for row in db.execute(
                select(jobs).where(jobs.c.id.in_(job_ids))).mappings()}
        return [found[j] for j in job_ids if j in found]

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
        if self.objects is not None:
            with self.db.transaction() as db:
                self._share(db, folder / name)

    def list_artefacts(self, job_id: str) -> list[tuple[str, int]]:
        """(name, size in bytes) of every artefact of a job, sorted by name."""
        folder = self.artefact_dir(job_id)
        if self.objects is not None:
            with self.db.read() as db:
                found = self.objects.listing(db, f"{self._key(folder)}/")
        elif folder.is_dir():
            found = [(p.name, p.stat().st_size) for p in folder.iterdir() if p.is_file()]
        else:
            found = []
        return sorted((name, size) for name, size in found if ARTEFACT_NAME.match(name))

    def artefact_path(self, job_id: str, name: str) -> Path | None:
        """Path of an artefact found by listing (a name is never used as a path)."""
        if name not in {n for n, _ in self.list_artefacts(job_id)}:
            return None
        path = self.artefact_dir(job_id) / name
        if self.objects is not None:
            self._fetch(path)  # always: a new attempt of the job may have replaced it
        return path

    def open_artefact(self, job_id: str, name: str) -> BinaryIO | None:
        """An artefact found by listing, opened for reading; None if the job has no such
        artefact, or no longer (deleted with its job)."""
        path = self.artefact_path(job_id, name)
        if path is not None:
            with suppress(FileNotFoundError):
                return open(path, "rb")
        return None


def _batch(row: RowMapping) -> BatchRecord:
    return BatchRecord(id=row["id"], owner=row["owner"], idempotency_key=row["idempotency_key"],
                       request_hash=row["request_hash"], job_ids=json.loads(row["job_ids"]),
                       created_at=row["created_at"])


def _lost_reason(attempts: int) -> str:
    return (f"the worker running this job stopped (killed, crashed or out of memory) on each "
            f"of {attempts} attempts; check the worker logs, give the worker more memory or "
            "submit a smaller problem")
