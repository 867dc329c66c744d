"""The task functions per job kind, and the entry point both queues call."""

from __future__ import annotations

from typing import Any

from service.settings import Settings
from service.store import Claim
from worker.analyses import analyse_job
from worker.identifications import identify_job
from worker.runner import Task, run_job
from worker.simulations import simulate_job
from worker.studies import create_study_job, diagnose_study_job, revise_study_job

TASKS: dict[str, Task] = {"simulation": simulate_job, "identification": identify_job,
                          "study": create_study_job, "study_revision": revise_study_job,
                          "study_diagnosis": diagnose_study_job, "analysis": analyse_job}


def execute(job_id: str, settings: dict[str, Any] | Settings,
            time_limit_errors: tuple[type[BaseException], ...] = ()) -> Claim:
    """Run one attempt of a job (see :func:`worker.runner.run_job`).

    Parameters
    ----------
    job_id : str
        Job to run.
    settings : Settings or dict
        Settings of the submitting process (a dict when sent to another process).
    time_limit_errors : tuple of exception types
        Exceptions that mean the execution environment's time limit was hit.
    """
    if not isinstance(settings, Settings):
        settings = Settings(**settings)
    return run_job(job_id, settings, TASKS, time_limit_errors)
