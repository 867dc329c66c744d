"""Celery application of fnsi-worker, configured so that no accepted job is lost.

* ``task_acks_late`` + ``task_reject_on_worker_lost``: a message is acknowledged only
  after its task ends, and requeued if the pool process running it dies;
* ``worker_prefetch_multiplier = 1``: a worker reserves only the tasks it can start,
  so an idle worker is never starved by a busy one;
* time limits below the Redis visibility timeout, so a task still running is never
  redelivered to a second worker;
* no result backend: job state lives in the job store (a Celery PENDING state would only
  mean "unknown"); the task is idempotent through the store's atomic claim;
* each message names the API's store (:attr:`service.store.Store.instance_id`): a worker
  on another data directory returns the message and stops, loudly, instead of
  acknowledging a job it cannot see;
* two message priorities (Redis keeps one list per priority and a worker empties the
  first before the last): a job re-queued after its worker died is published at
  :data:`FIRST` and runs before the jobs that were waiting behind it.
"""

from __future__ import annotations

import logging
import os

from celery import Celery, Task
from celery.exceptions import Reject, SoftTimeLimitExceeded
from celery.signals import worker_process_init

from service.settings import Settings, get_settings
from service.store import Store
from worker.job_process import become_job_process
from worker.tasks import execute

log = logging.getLogger("fnsi.worker")

TASK_NAME = "fnsi.run_job"
# Message priorities on Redis: 0 is served first (kombu's priority steps 0, 3, 6, 9).
FIRST, LAST = 0, 9


def make_celery(settings: Settings) -> Celery:
    """Celery app for ``settings`` (broker, queue, limits) with the job task registered."""
    app = Celery("fnsi", broker=settings.broker_url or "memory://", set_as_current=False)
    app.conf.update(
        task_acks_late=True,
        task_reject_on_worker_lost=True,
        worker_prefetch_multiplier=1,
        task_soft_time_limit=settings.job_time_limit,
        task_time_limit=settings.job_time_limit + 30,
        broker_transport_options={"visibility_timeout": settings.visibility_timeout,
                                  "priority_steps": [FIRST, LAST],
                                  "queue_order_strategy": "priority"},
        broker_connection_retry_on_startup=True,
        task_default_queue=settings.queue_name,
        task_ignore_result=True,
        task_serializer="json",
        accept_content=["json"],
        worker_hijack_root_logger=False,
    )

    @app.task(name=TASK_NAME, bind=True, max_retries=None)
    def run_job(self, job_id: str, store: str | None = None) -> None:
        refuse_foreign(self, store, settings)
        claim = execute(job_id, settings, (SoftTimeLimitExceeded,))
        if claim.retry_after is not None:  # another worker's lease is alive: look again later
            raise self.retry(countdown=claim.retry_after + 1.0)

    return app


def refuse_foreign(task: Task, store: str | None, settings: Settings) -> None:
    """Return the message and stop consuming when the job was queued by an API on another
    data directory (``store``: the instance id of the API's store; None in a message of an
    older API): this worker would not find the job and must not swallow it.

    Raises
    ------
    celery.exceptions.Reject
        With ``requeue``, so that a worker on the right FNSI_DATA_DIR runs the job.
    """
    ours = Store.from_settings(settings).instance_id
    if store is None or store == ours:
        return
    log.error("FNSI_DATA_DIR %s is not the data directory of the API that queued this job "
              "(its store is %s, this one %s): returning the message and consuming no more; "
              "restart fnsi-worker with the API's FNSI_DATA_DIR (a shared mount) or, when "
              "the API keeps its records in PostgreSQL, with its FNSI_DATABASE_URL",
              settings.data_dir, store, ours)
    task.app.control.cancel_consumer(settings.queue_name, destination=[task.request.hostname])
    raise Reject(f"foreign FNSI_DATA_DIR {settings.data_dir}", requeue=True)


app = make_celery(get_settings())


@worker_process_init.connect(weak=False, dispatch_uid="fnsi-job-process")
def _job_process(**_: object) -> None:
    """Each pool child of fnsi-worker is a job process (lower priority, ends with the
    worker). The kernel's parent-death signal is not asked for: the pool may fork from a
    thread that ends before the worker; the lease renewal checks the parent instead."""
    become_job_process(os.getppid(), get_settings().job_nice, die_with_parent=False)
