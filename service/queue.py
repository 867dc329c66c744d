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
killed) or fails them after FNSI_MAX_ATTEMPTS, publishes again jobs queued for longer
than FNSI_REQUEUE_AFTER (a message lost with the broker), and deletes jobs finished
longer than FNSI_JOB_RETENTION_DAYS ago.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import threading
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from queue import SimpleQueue
from typing import Protocol

from service.retention import delete_expired_jobs
from service.settings import Settings
from service.store import JobState, StaleJob, Store
from worker.job_process import become_job_process
from worker.tasks import execute

log = logging.getLogger("fnsi.service")

# How often [s] the embedded dispatcher looks for queued jobs without being woken.
_POLL_INTERVAL = 1.0


class JobQueue(Protocol):
    """Something that eventually runs queued jobs."""

    name: str

    def submit(self, job_id: str, *, first: bool = False) -> None:
        """Hand over a queued job; ``first``: ahead of new jobs (it was re-queued)."""

    def start(self) -> None:
        """Start background machinery."""

    def stop(self) -> None:
        """Stop background machinery (running jobs are left to the supervisor)."""

    def resubmit_stale(self) -> list[StaleJob]:
        """Hand over again queued jobs whose hand-over may have been lost."""


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

    def submit(self, job_id: str, *, first: bool = False) -> None:
        """Wake the dispatcher (it starts re-queued jobs first in any case)."""
        self._wake.set()

    def resubmit_stale(self) -> list[StaleJob]:
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
    """Publishes jobs to fnsi-worker processes through the broker.

    Publishing happens on a thread of its own, so a request never waits for the broker
    (an unreachable Redis takes seconds to refuse): the job is recorded before it is
    handed over here, and one whose message could not be sent is published again by the
    supervisor (:meth:`resubmit_stale`). Re-queued jobs go out at the broker's first
    priority, new ones at its last, so a job whose worker died runs next.
    """

    name = "celery"

    def __init__(self, settings: Settings, store: Store) -> None:
        from worker.celery_app import FIRST, LAST, TASK_NAME, make_celery

        self.settings, self.store = settings, store
        self._app = make_celery(settings)
        self._task_name, self._priorities = TASK_NAME, (LAST, FIRST)
        self._outbox: SimpleQueue[tuple[str, bool] | None] = SimpleQueue()
        self._waiting: set[str] = set()  # in the outbox or being sent: not sent twice
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._publish_loop, daemon=True,
                                        name="fnsi-publisher")

    def start(self) -> None:
        self._thread.start()
        # Messages of jobs still queued may have been lost with a broker that restarted
        # without persistence; publishing again is safe because claims are atomic.
        for job in self.store.jobs_in_state(JobState.QUEUED):
            self.submit(job.id, first=job.attempts > 0)

    def stop(self) -> None:
        """Stop publishing (jobs not yet published stay queued in the store)."""
        self._outbox.put(None)
        self._thread.join(timeout=10)

    def submit(self, job_id: str, *, first: bool = False) -> None:
        with self._lock:
            if job_id in self._waiting:
                return
            self._waiting.add(job_id)
        self._outbox.put((job_id, first))

    def _publish_loop(self) -> None:
        while (item := self._outbox.get()) is not None:
            job_id, first = item
            try:
                self._publish(job_id, first)
            finally:
                with self._lock:
                    self._waiting.discard(job_id)

    def _publish(self, job_id: str, first: bool) -> None:
        try:
            self._app.send_task(self._task_name, args=[job_id],
                                kwargs={"store": self.store.instance_id},
                                queue=self.settings.queue_name,
                                priority=self._priorities[first], retry=False)
        except Exception:  # kombu raises its own and socket errors; the store keeps the job
            log.warning("broker unreachable: job %s stays queued and is published by the "
                        "supervisor when the broker answers", job_id, exc_info=True)
            return
        try:
            self.store.mark_enqueued(job_id)
        except Exception:  # database out of reach: the supervisor publishes it again later
            log.warning("job %s published but its publication time was not stored",
                        job_id, exc_info=True)

    def resubmit_stale(self) -> list[StaleJob]:
        """Publish again the jobs never published, or published longer than
        FNSI_REQUEUE_AFTER ago and still queued."""
        stale = self.store.stale_queued(self.settings.requeue_after)
        for job in stale:
            self.submit(job.id, first=job.attempts > 0)
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
            self.queue.submit(job_id, first=True)
        for job in self.queue.resubmit_stale():
            if job.published_ago is None:
                log.warning("job %s, queued %.0f s ago, is not published yet (broker "
                            "unreachable); publishing again", job.id, job.created_ago)
            else:
                log.warning("job %s still queued %.0f s after it was published; published "
                            "again", job.id, job.published_ago)
        for job_id in delete_expired_jobs(self.settings, self.store):
            log.info("job %s deleted: finished more than FNSI_JOB_RETENTION_DAYS ago", job_id)

    def _loop(self) -> None:
        while not self._stopping.wait(self.settings.supervisor_interval):
            try:
                self.check()
            except Exception:
                log.exception("supervisor error")


def make_queue(settings: Settings, store: Store) -> JobQueue:
    """Celery queue when a broker is configured, else the embedded runner."""
    return CeleryQueue(settings, store) if settings.broker_url else EmbeddedQueue(settings, store)
