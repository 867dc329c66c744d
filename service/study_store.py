"""Studies on disk under FNSI_DATA_DIR: who owns them and their latest saved state.

A study (:class:`fnsi.study.Study`) changes only by whole revisions, each computed by one
job. Its state is kept as immutable snapshots written by :meth:`fnsi.study.Study.save`
into the store's tmp folder and renamed into place, so a reader always sees a complete
study and a job that dies while saving leaves the previous revision intact. Jobs of a
study are ordinary jobs whose request names it (``study_id``); their order is the job
sequence of the store. Revision jobs take the study's lock (:meth:`Database.held_lock
<service.database.Database.held_lock>`: ``flock`` on SQLite, an advisory lock on
PostgreSQL; both released when a worker dies), so two revisions never read the same
state and overwrite each other's result.

With FNSI_BLOB_STORE=database every file below is also a shared object (a snapshot's
files all in one transaction, before it is renamed into place), and each host's folder
is a cache of them: hosts share studies without sharing a folder.

Layout::

    <data_dir>/studies/<study_id>/record.json        owner, name, creation request
    <data_dir>/studies/<study_id>/lock               held while a revision is computed
    <data_dir>/studies/<study_id>/revisions-<n>/     snapshot with n revisions:
        study.json, estimation.npz, validation.npz, revisions.npz (Study.save) and
        producers.json (the job that computed each revision)
"""

from __future__ import annotations

import json
import os
import re
import shutil
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from fnsi.html_report import DiagnosisPart, study_page
from fnsi.study import Study
from service.store import JobRecord, Store, new_id, now_iso

STUDY_ID = re.compile(r"^study_[0-9a-f]{20}$")
_SNAPSHOT = re.compile(r"^revisions-(?P<count>[0-9]+)$")
# How often [s] a job waiting for the study's lock or earlier revisions looks again.
_WAIT_INTERVAL = 0.5


@dataclass(frozen=True)
class StudyRecord:
    """A study as its owner created it; ``request`` is the validated creation request."""

    id: str
    owner: str
    name: str
    created_at: str
    request: dict[str, Any]


@dataclass(frozen=True)
class Snapshot:
    """The latest saved state of a study, as read for a response (no arrays loaded).

    Attributes
    ----------
    folder : Path
        Snapshot folder (give to :meth:`fnsi.study.Study.load`).
    study : dict
        ``study.json``: settings, revisions with their validation errors, history.
    producers : list of str
        Id of the job that computed each revision.
    """

    folder: Path
    study: dict[str, Any]
    producers: list[str]


class StudyStore:
    """Studies kept beside the job store.

    Parameters
    ----------
    store : Store
        The job and dataset store; studies live in its data directory.
    """

    def __init__(self, store: Store) -> None:
        self.store = store
        self.root = store.root / "studies"
        self.root.mkdir(parents=True, exist_ok=True)

    def folder(self, study_id: str) -> Path:
        """Folder of a study; ValueError for anything but a study id (no path tricks)."""
        if not STUDY_ID.match(study_id):
            raise ValueError(f"{study_id!r} is not a study id")
        return self.root / study_id

    # -- records ----------------------------------------------------------------------------
    def create(self, owner: str, name: str, request: dict[str, Any]) -> StudyRecord:
        """Record a new study of ``owner`` (atomically: a reader sees all of it or none)."""
        record = StudyRecord(new_id("study"), owner, name, now_iso(), request)
        folder = self.folder(record.id)
        folder.mkdir()
        with self.store.partial_file(".json") as partial:
            partial.write_text(json.dumps(asdict(record)))
            self.store.share_file(folder / "record.json", partial)
            os.replace(partial, folder / "record.json")
        return record

    def get(self, study_id: str) -> StudyRecord | None:
        """The study's record, or None if there is no such study."""
        if not STUDY_ID.match(study_id):
            return None
        path = self.store.cached(self.folder(study_id) / "record.json")
        if not path.is_file():
            return None
        return StudyRecord(**json.loads(path.read_text()))

    def owned_by(self, owner: str, *, before: tuple[str, str] | None = None,
                 limit: int = 50) -> list[StudyRecord]:
        """Studies of ``owner``, newest first (by creation time, then id); ``before`` pages
        with the ``(created_at, id)`` of the last study of the previous page. Reads every
        study's record: meant for a lab's hundreds of studies, not for millions."""
        shared = self.store.shared_files(self.root)
        study_ids = ({name.split("/")[0] for name in shared} if shared is not None
                     else {folder.name for folder in self.root.iterdir()})
        records = []
        for study_id in sorted(study_ids):
            record = self.get(study_id)
            if record is not None and record.owner == owner:
                records.append(record)
        records.sort(key=lambda r: (r.created_at, r.id), reverse=True)
        if before is not None:
            records = [r for r in records if (r.created_at, r.id) < before]
        return records[:limit]

    def jobs(self, study_id: str, owner: str) -> list[JobRecord]:
        """Every job of the study, oldest first."""
        return self.store.jobs_of_study(study_id, owner)

    # -- snapshots --------------------------------------------------------------------------
    def _snapshots(self, study_id: str) -> list[tuple[int, Path]]:
        folder = self.folder(study_id)
        shared = self.store.shared_files(folder)
        if shared is not None:
            names = {name.split("/")[0] for name in shared if "/" in name}
        else:
            names = {p.name for p in folder.iterdir() if p.is_dir()} if folder.is_dir() else set()
        return sorted((int(m["count"]), folder / name) for name in names
                      if (m := _SNAPSHOT.match(name)))

    def _fetched(self, folder: Path) -> Path:
        """A snapshot folder with all its files on this host (snapshots never change)."""
        for name in self.store.shared_files(folder) or []:
            self.store.cached(folder / name)
        return folder

    def snapshot(self, study_id: str) -> Snapshot | None:
        """The latest saved state, or None before revision 0 is saved."""
        for _ in range(3):  # a snapshot pruned between listing and reading: list again
            snapshots = self._snapshots(study_id)
            if not snapshots:
                return None
            folder = snapshots[-1][1]
            try:
                return Snapshot(folder, json.loads(self._read(folder / "study.json")),
                                json.loads(self._read(folder / "producers.json")))
            except FileNotFoundError:
                continue
        raise RuntimeError(f"study {study_id}: snapshots keep disappearing while read")

    def load(self, study_id: str) -> tuple[Study, list[str]] | None:
        """The latest saved study and the producer of each revision, or None."""
        snapshot = self.snapshot(study_id)
        if snapshot is None:
            return None
        return Study.load(self._fetched(snapshot.folder)), snapshot.producers

    def _read(self, path: Path) -> str:
        return self.store.cached(path).read_text()

    def save(self, study_id: str, study: Study, producers: list[str]) -> Path:
        """Save ``study`` as its newest snapshot; keep the one before (for readers still
        on it) and remove older ones. Call while holding :meth:`locked`."""
        count = len(study.revisions)
        partial = Path(tempfile.mkdtemp(dir=self.store.tmp, prefix=f"{study_id}-"))
        try:
            study.save(partial)
            (partial / "producers.json").write_text(json.dumps(producers))
            final = self.folder(study_id) / f"revisions-{count}"
            self.store.share_folder(final, partial)
            final.parent.mkdir(exist_ok=True)  # a study created on another host
            os.rename(partial, final)
        except BaseException:
            shutil.rmtree(partial, ignore_errors=True)
            raise
        for number, folder in self._snapshots(study_id):
            if number < count - 1:
                self.store.unshare_folder(folder)
                shutil.rmtree(folder, ignore_errors=True)
        return final

    @contextmanager
    def locked(self, study_id: str, wait: Callable[[], None]) -> Iterator[None]:
        """Hold the study's lock; ``wait()`` is called between tries (it may raise to
        give up, e.g. when the job is cancelled)."""
        with self.store.db.held_lock(f"study:{study_id}", self.folder(study_id) / "lock",
                                     wait):
            yield

    def wait_for_earlier_revisions(self, job: JobRecord, wait: Callable[[str], None]) -> None:
        """Return once every revision job of the study submitted before ``job`` ended, so
        that revisions apply in the order they were requested. ``wait(message)`` is
        called between looks (it may raise to give up)."""
        study_id = job.request["study_id"]
        while True:
            pending = [j for j in self.jobs(study_id, job.owner)
                       if j.seq < job.seq and j.kind != "study_diagnosis"
                       and j.state in ("queued", "running")]
            if not pending:
                return
            wait(f"waiting for job {pending[0].id} ({pending[0].kind}) of the study")
            time.sleep(_WAIT_INTERVAL)

    # -- report -----------------------------------------------------------------------------
    def report(self, study_id: str, owner: str) -> bytes | None:
        """The study's one-page HTML report (:func:`fnsi.html_report.study_page`) from its
        latest snapshot, the figures of the jobs that computed each revision and every
        diagnosis that succeeded; None before revision 0 is saved."""
        snapshot = self.snapshot(study_id)
        if snapshot is None:
            return None
        figures = self._artefacts(snapshot.producers[-1], ("history.png",))
        for number, job_id in enumerate(snapshot.producers):
            figures |= self._artefacts(job_id, (f"revision-{number}-",))
        diagnoses = [DiagnosisPart(json.loads(files.pop("diagnosis.json")), files)
                     for job in self.jobs(study_id, owner)
                     if job.kind == "study_diagnosis" and job.state == "succeeded"
                     and "diagnosis.json" in (files := self._artefacts(job.id, ("",)))]
        return study_page(snapshot.study, figures, diagnoses)

    def _artefacts(self, job_id: str, prefixes: tuple[str, ...]) -> dict[str, bytes]:
        """Artefacts of a job whose names start with one of ``prefixes``, by name."""
        found = {}
        for name, _ in self.store.list_artefacts(job_id):
            file = self.store.open_artefact(job_id, name) if name.startswith(prefixes) else None
            if file is not None:
                with file:
                    found[name] = file.read()
        return found
