"""Queue adapters: how the API hands a queued job to something that runs it.

Both adapters run the same task function (:func:`worker.tasks.execute`); the job store,
not the queue, holds job state, so either can lose or repeat a hand-over safely:

* :class:`EmbeddedQueue` (no broker): a dispatcher thread takes queued jobs from the store,
  oldest first, and runs them in a small process pool, so a long job never blocks a
  request and a crashing job cannot take the API down. Jobs a previous API process left
  queued are simply picked up; those it left running are re-queued by the supervisor once
  their lease expires.
* :class:`CeleryQueue` (FNSI_BROKER_URL set): publishes a task message per job for
  ``fnsi-worker`` processes.

A supervisor thread (both modes) re-queues running jobs whose lease expired (worker
killed) or fails them after FNSI_MAX_ATTEMPTS, and publishes again jobs queued for longer
than FNSI_REQUEUE_AFTER (a message lost with the broker).
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import threading
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Protocol

from service.settings import Settings
from service.store import JobState, Store
from worker.job_process import become_job_process
from worker.tasks import execute

log = logging.getLogger("fnsi.service")

# How often [s] the embedded dispatcher looks for queued jobs without being woken.
_POLL_INTERVAL = 1.0


class JobQueue(Protocol):
    """Something that eventually runs queued jobs."""

    name: str

    def submit(self, job_id: str) -> None:
        """Hand over a queued job."""

    def start(self) -> None:
        """Start background machinery."""

    def stop(self) -> None:
        """Stop background machinery (running jobs are left to the supervisor)."""

    def resubmit_stale(self) -> list[str]:
        """Hand over again queued jobs whose hand-over may have been lost; their ids."""


class EmbeddedQueue:
    """Runs jobs in a process pool owned by the API process."""

    name = "embedded"

    def __init__(self, settings: Settings, store: Store) -> None:
        self.settings, self.store = settings, store
        self._wake = threading.Event()
        self._stopping = threading.Event()
        self._running: dict[str, Future] = {}
        self._pool: ProcessPoolExecutor | None = None
        self._thread = threading.Thread(target=self._dispatch, daemon=True,
                                        name="fnsi-dispatcher")

    def _new_pool(self) -> ProcessPoolExecutor:
        # spawn: forking a process that runs threads (uvicorn, this dispatcher) is unsafe.
        # The pool starts its processes from the dispatcher thread, which lives as long as
        # the API, so they may ask the kernel to end them with the API.
        return ProcessPoolExecutor(self.settings.embedded_workers,
                                   mp_context=multiprocessing.get_context("spawn"),
                                   initializer=become_job_process,
                                   initargs=(os.getpid(), self.settings.job_nice, True))

    def start(self) -> None:
        self._pool = self._new_pool()
        self._thread.start()

    def stop(self) -> None:
        self._stopping.set()
        self._wake.set()
        self._thread.join(timeout=10)
        if self._pool is not None:
            # The executor has no public way to stop running work; a killed attempt is
            # re-queued through its lease by the next API process.
            for process in list((getattr(self._pool, "_processes", None) or {}).values()):
                process.kill()
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None

    def submit(self, job_id: str) -> None:
        self._wake.set()

    def resubmit_stale(self) -> list[str]:
        """Nothing to do: the dispatcher reads queued jobs from the store itself."""
        return []

    def _dispatch(self) -> None:
        while not self._stopping.is_set():
            self._wake.wait(_POLL_INTERVAL)
            self._wake.clear()
            if self._stopping.is_set():
                return
            try:
                self._collect()
                self._start_queued()
            except Exception:
                log.exception("embedded dispatcher error")

    def _collect(self) -> None:
        for job_id, future in list(self._running.items()):
            if not future.done():
                continue
            del self._running[job_id]
            if isinstance(future.exception(), BrokenProcessPool):
                # A pool process died (killed, out of memory): the supervisor re-queues
                # its job when the lease expires; the pool itself must be rebuilt.
                log.error("embedded worker process died while running %s", job_id)
                self._pool.shutdown(wait=False, cancel_futures=True)
                self._pool = self._new_pool()
                self._running.clear()
                return

    def _start_queued(self) -> None:
        free = self.settings.embedded_workers - len(self._running)
        if free <= 0:
            return
        # Re-queued jobs (an attempt was lost with its process) first, then oldest first.
        queued = sorted(self.store.jobs_in_state(JobState.QUEUED),
                        key=lambda job: (job.attempts == 0, job.seq))
        for job in queued:
            if free == 0:
                break
            if job.id in self._running:
                continue
            future = self._pool.submit(execute, job.id, self.settings.model_dump(mode="json"))
            future.add_done_callback(lambda _: self._wake.set())
            self._running[job.id] = future
            free -= 1


class CeleryQueue:
    """Publishes jobs to fnsi-worker processes through the broker."""

    name = "celery"

    def __init__(self, settings: Settings, store: Store) -> None:
        from worker.celery_app import TASK_NAME, make_celery

        self.settings, self.store = settings, store
        self._app = make_celery(settings)
        self._task_name = TASK_NAME

    def start(self) -> None:
        # Messages of jobs still queued may have been lost with a broker that restarted
        # without persistence; publishing again is safe because claims are atomic.
        for job in self.store.jobs_in_state(JobState.QUEUED):
            self.submit(job.id)

    def stop(self) -> None:
        """Nothing to stop: workers run independently."""

    def submit(self, job_id: str) -> None:
        try:
            self._app.send_task(self._task_name, args=[job_id], queue=self.settings.queue_name,
                                retry=False)
        except Exception:  # kombu raises its own and socket errors; the store keeps the job
            log.warning("broker unreachable: job %s stays queued and is published by the "
                        "supervisor when the broker answers", job_id, exc_info=True)
            return
        self.store.mark_enqueued(job_id)

    def resubmit_stale(self) -> list[str]:
        """Publish again the jobs queued for longer than FNSI_REQUEUE_AFTER."""
        stale = self.store.stale_queued(self.settings.requeue_after)
        for job_id in stale:
            self.submit(job_id)
        return stale


class Supervisor:
    """Periodically re-queues or fails jobs whose worker stopped renewing the lease."""

    def __init__(self, settings: Settings, store: Store, queue: JobQueue) -> None:
        self.settings, self.store, self.queue = settings, store, queue
        self._stopping = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True, name="fnsi-supervisor")

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stopping.set()
        self._thread.join(timeout=10)

    def check(self) -> None:
        """One pass: hand re-queued jobs to the queue again."""
        for job_id in self.store.reap_lost(self.settings.max_attempts):
            log.warning("job %s lost its worker; re-queued", job_id)
            self.queue.submit(job_id)
        for job_id in self.queue.resubmit_stale():
            log.warning("job %s still queued after %g s; published again", job_id,
                        self.settings.requeue_after)

    def _loop(self) -> None:
        while not self._stopping.wait(self.settings.supervisor_interval):
            try:
                self.check()
            except Exception:
                log.exception("supervisor error")


def make_queue(settings: Settings, store: Store) -> JobQueue:
    """Celery queue when a broker is configured, else the embedded runner."""
    return CeleryQueue(settings, store) if settings.broker_url else EmbeddedQueue(settings, store)
