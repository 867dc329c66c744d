"""Retention of finished jobs: FNSI_JOB_RETENTION_DAYS, applied by the API's supervisor."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

from service.schema import STUDY_JOB_KINDS
from service.settings import Settings
from service.store import Store


def delete_expired_jobs(settings: Settings, store: Store) -> list[str]:
    """Delete the jobs that finished more than FNSI_JOB_RETENTION_DAYS ago, with their
    artefacts (jobs of a study stay: their artefacts are the study's figures); their ids.
    Nothing without the setting."""
    if settings.job_retention_days is None:
        return []
    cutoff = datetime.now(UTC) - timedelta(days=settings.job_retention_days)
    return store.delete_jobs_finished_before(cutoff.isoformat(timespec="milliseconds"),
                                             STUDY_JOB_KINDS)
