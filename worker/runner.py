"""Run one job attempt: claim it, keep its lease alive, report progress, store the outcome.

The same function runs in a Celery worker and in the API's embedded runner, so a job
behaves identically on both. The job store is the single source of truth:

* :meth:`Store.claim` starts an attempt atomically, so a redelivered message (Redis
  visibility timeout, a requeue after a lost worker) never runs a job twice at once;
* a heartbeat thread renews the lease while the attempt runs, so a killed process is
  noticed when its lease expires and the job is re-queued or failed, never left running;
* every write of an attempt names it (its attempt number): an attempt that lost its lease
  while the database was out of reach (the job was re-queued meanwhile) stops and stores
  nothing, so at most one attempt of a job completes; a database outage shorter than the
  lease costs nothing (reports are retried, the outcome is stored once it answers);
* the progress callback handed to the library stores progress and raises
  :class:`JobCancelledError` once a cancel was requested, or :class:`JobTimeLimitError` past the
  time limit, which stops the computation at its next report.
"""

from __future__ import annotations

import errno
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from service.database import unreachable
from service.settings import Settings
from service.store import Claim, JobRecord, JobState, LeaseLostError, Store
from worker.job_process import exit_if_orphaned

log = logging.getLogger("fnsi.worker")

Progress = Callable[[float, str], None]


@dataclass(frozen=True)
class JobContext:
    """What a task function gets: the store, its job record, the progress callback (which
    raises to stop the task) and the settings of the process running it."""

    store: Store
    job: JobRecord
    progress: Progress
    settings: Settings


Task = Callable[[JobContext], dict[str, Any]]

# Progress is written at most this often [s]; libraries may report every few ms.
_REPORT_INTERVAL = 0.25
# How long [s] an ended attempt keeps trying to store its outcome while the database is
# out of reach (a restart takes seconds); after that the job's lease lapses and it re-runs.
_OUTCOME_PATIENCE = 300.0


class JobCancelledError(Exception):
    """The job's owner cancelled it."""


class JobTimeLimitError(Exception):
    """The attempt ran longer than FNSI_JOB_TIME_LIMIT."""


class Attempt:
    """A running attempt: lease heartbeat, throttled progress, cancel and deadline checks."""

    def __init__(self, store: Store, job_id: str, number: int, settings: Settings) -> None:
        self.store, self.job_id, self.number, self.settings = store, job_id, number, settings
        self.deadline = time.monotonic() + settings.job_time_limit
        self.cancelled = threading.Event()
        self.lost = threading.Event()
        self._stop = threading.Event()
        self._last_report = 0.0
        self._heartbeat = threading.Thread(target=self._beat, daemon=True,
                                           name=f"lease-{job_id}")

    def __enter__(self) -> Attempt:
        self._heartbeat.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._heartbeat.join()

    def _beat(self) -> None:
        while not self._stop.wait(self.settings.lease_seconds / 4):
            exit_if_orphaned(self.job_id)  # before renewing: an orphan's lease must lapse
            self._report()

    def _report(self, **progress: Any) -> None:
        """Renew the lease (with ``progress`` and ``message``); note a cancel or a lost
        lease. A database out of reach is only logged: the next report tries again."""
        try:
            if self.store.report(self.job_id, lease_seconds=self.settings.lease_seconds,
                                 attempt=self.number, **progress):
                self.cancelled.set()
        except LeaseLostError:
            self.lost.set()
        except Exception as err:
            if not unreachable(err):
                raise
            log.warning("job %s: database out of reach, lease not renewed (%s)",
                        self.job_id, type(err).__name__)

    def progress(self, fraction: float, message: str) -> None:
        """Callback for the library: record progress, stop if cancelled, lost or out of
        time."""
        now = time.monotonic()
        if now - self._last_report >= _REPORT_INTERVAL or fraction >= 1.0:
            self._last_report = now
            fraction = min(max(float(fraction), 0.0), 1.0)
            self._report(progress=fraction, message=str(message)[:500])
        if self.lost.is_set():
            raise LeaseLostError(self.job_id, self.number)
        if self.cancelled.is_set():
            raise JobCancelledError
        if now > self.deadline:
            raise JobTimeLimitError


def run_job(job_id: str, settings: Settings, tasks: dict[str, Task],
            time_limit_errors: tuple[type[BaseException], ...] = ()) -> Claim:
    """Run one attempt of ``job_id`` if it can be claimed; store its outcome.

    Parameters
    ----------
    job_id : str
        Job to run.
    settings : Settings
        Data directory, lease and limits.
    tasks : dict
        Task function per job kind.
    time_limit_errors : tuple of exception types
        Exceptions the execution environment raises at its time limit (Celery's soft limit).

    Returns
    -------
    Claim
        What the claim decided; ``retry_after`` set when another worker holds the lease.
    """
    store = Store.from_settings(settings)
    claim = store.claim(job_id, lease_seconds=settings.lease_seconds,
                        max_attempts=settings.max_attempts)
    if not claim.run:
        level = logging.ERROR if claim.reason == "unknown job" else logging.INFO
        log.log(level, "job %s not run: %s (FNSI_DATA_DIR %s)", job_id, claim.reason,
                settings.data_dir)
        return claim
    job = store.get_job(job_id)
    log.info("job %s (%s) attempt %d started", job_id, job.kind, claim.attempt)
    with Attempt(store, job_id, claim.attempt, settings) as attempt:
        try:
            outcome = _outcome(tasks[job.kind], JobContext(store, job, attempt.progress,
                                                           settings), time_limit_errors)
            if outcome is not None:
                _store_outcome(store, attempt, *outcome)
        except LeaseLostError:
            log.warning("job %s: attempt %d lost its lease (the job was re-queued while the "
                        "database was out of reach); stopped, nothing stored", job_id,
                        claim.attempt)
    log.info("job %s ended", job_id)
    return claim


def _outcome(task: Task, context: JobContext,
             time_limit_errors: tuple[type[BaseException], ...]
             ) -> tuple[JobState, dict[str, Any]] | None:
    """How the attempt ended: the job's state and what to store with it; None when the
    database went out of reach during the task (the attempt is abandoned: its lease lapses
    and the job runs again)."""
    settings = context.settings
    try:
        result = task(context)
    except JobCancelledError:
        return JobState.CANCELLED, {"message": "cancelled while running"}
    except (JobTimeLimitError, *time_limit_errors):
        return JobState.FAILED, {"error": (
            f"the job exceeded the time limit of {settings.job_time_limit:g} s; submit a "
            "smaller problem (fewer samples, outputs or a lower max_order) or ask the "
            "operator to raise FNSI_JOB_TIME_LIMIT")}
    except ValueError as err:  # the library's message names the fault and the fix
        return JobState.FAILED, {"error": str(err)}
    except LeaseLostError:
        raise
    except Exception as err:
        if unreachable(err):
            log.warning("job %s: database out of reach during the task; attempt abandoned, "
                        "the job re-runs once its lease lapses", context.job.id)
            return None
        return JobState.FAILED, {"error": _unexpected(context.job.id, err)}
    return JobState.SUCCEEDED, {"result": result, "message": "done"}


def _store_outcome(store: Store, attempt: Attempt, state: JobState,
                   outcome: dict[str, Any]) -> None:
    """Finish the job as ``attempt``, waiting out a database restart (the heartbeat keeps
    the lease meanwhile); LeaseLostError if the job was re-queued in between."""
    deadline = time.monotonic() + _OUTCOME_PATIENCE
    while True:
        try:
            store.finish(attempt.job_id, state, attempt=attempt.number, **outcome)
            log.info("job %s attempt %d stored its outcome: %s", attempt.job_id,
                     attempt.number, state.value)
            return
        except Exception as err:
            if not unreachable(err) or time.monotonic() > deadline:
                raise
            time.sleep(1.0)


def _unexpected(job_id: str, err: Exception) -> str:
    """Error message of a job that failed other than by a ValueError of the library."""
    if isinstance(err, OSError) and err.errno == errno.ENOSPC:
        return ("the server ran out of disk space while storing the results; nothing stored "
                "earlier was lost. Resubmit once the operator has freed space under "
                "FNSI_DATA_DIR")
    log.exception("job %s failed", job_id)
    return f"internal error ({type(err).__name__}: {err}); please report it"
