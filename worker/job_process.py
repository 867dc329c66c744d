"""Job processes: tied to the life of the process that started them, and below its
scheduling priority.

A job process (the embedded runner's pool processes, the Celery worker's pool children)
must never outlive its parent: an orphan would keep renewing its job's lease, so a
restarted API could neither resume that job nor keep to FNSI_EMBEDDED_WORKERS beside it.
Two guards, because either alone has a gap:

* on Linux the kernel sends SIGKILL when the parent dies (``prctl(PR_SET_PDEATHSIG)``);
* every lease renewal checks that the parent is still the one the process started under
  (:func:`orphaned`), which also covers a parent that died before ``prctl`` took effect
  and systems without ``prctl``.

Job processes compute at a lower priority (``os.nice``) so that the API on the same
machine answers status polls promptly while its jobs run.
"""

from __future__ import annotations

import ctypes
import logging
import os
import signal
import sys

log = logging.getLogger("fnsi.worker")

_PR_SET_PDEATHSIG = 1  # <linux/prctl.h>

# Pid of the parent this process must not outlive; None in a process that is no job
# process (a test calling the runner directly, a Celery solo worker).
_parent: int | None = None


def become_job_process(parent: int, nice: int, die_with_parent: bool) -> None:
    """Make the calling process a job process of ``parent`` (pool initializer).

    Parameters
    ----------
    parent : int
        Pid of the process that started this one (read there, before starting it, so a
        parent that already died is noticed).
    nice : int
        Increment of the scheduling niceness (0: the parent's priority).
    die_with_parent : bool
        Ask the kernel for SIGKILL when the parent dies. Only for a parent whose
        starting thread lives as long as it: Linux sends the signal when that *thread*
        ends.
    """
    global _parent
    _parent = parent
    if die_with_parent and sys.platform.startswith("linux"):
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) != 0:
            log.warning("prctl(PR_SET_PDEATHSIG) failed (errno %d); the lease renewal "
                        "still ends this process if its parent dies", ctypes.get_errno())
    if orphaned():  # the parent died before the kernel was told
        os._exit(1)
    if nice:
        os.nice(nice)


JOB_CPUS = "FNSI_JOB_CPUS"
"""Environment variable through which a launcher tells its job processes how many CPUs
each may keep busy (:func:`share_cpus`)."""


def share_cpus(concurrent_jobs: int) -> int:
    """Divide this machine's CPUs among ``concurrent_jobs`` job processes (at least one
    each) and export the share to the processes started from here: as
    ``OPENBLAS_NUM_THREADS`` (threaded BLAS under contention was seen 100x slower) and
    as :data:`JOB_CPUS`, the threads a diagnosis validates its candidates with
    (:func:`job_cpus`). Values already in the environment are kept.

    Returns
    -------
    int
        The share.
    """
    share = max(1, (os.cpu_count() or 1) // max(1, concurrent_jobs))
    os.environ.setdefault("OPENBLAS_NUM_THREADS", str(share))
    os.environ.setdefault(JOB_CPUS, str(share))
    return share


def job_cpus() -> int | None:
    """CPUs this job process may keep busy (:func:`share_cpus`); None where no launcher
    said (the library's defaults then apply)."""
    value = os.environ.get(JOB_CPUS, "")
    return max(1, int(value)) if value.isdigit() else None


def orphaned() -> bool:
    """Whether this is a job process whose parent died (it was re-parented)."""
    return _parent is not None and os.getppid() != _parent


def exit_if_orphaned(job_id: str) -> None:
    """End this process at once if its parent died: its job is re-queued when the lease
    expires, by the parent's successor, and must not run twice meanwhile."""
    if orphaned():
        log.error("job %s: the process that started this job process (pid %d) is gone; "
                  "stopping so that the job is re-queued, not run twice", job_id, _parent)
        os._exit(1)
