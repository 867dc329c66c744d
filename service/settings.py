"""Configuration of the API and the workers, read from ``FNSI_*`` environment variables."""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, field_validator, model_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

from service.database import check_database_url


class Settings(BaseSettings):
    """Every setting of fnsi-service and fnsi-worker; env var = ``FNSI_`` + field name."""

    model_config = SettingsConfigDict(env_prefix="FNSI_", extra="ignore")

    data_dir: Path = Field(
        Path("data"),
        description="Directory holding the job store, datasets and artefacts; "
        "shared by the API and the workers.",
    )
    broker_url: str | None = Field(
        None,
        description="Celery broker (e.g. redis://127.0.0.1:6379/0). Unset: the API runs "
        "jobs itself on an embedded runner.",
    )
    api_keys: Annotated[list[str], NoDecode] = Field(
        default_factory=list,
        description="Comma-separated API keys accepted in the X-API-Key header. Empty: no "
        "authentication, every caller shares one namespace.",
    )
    max_upload_bytes: int = Field(
        2 * 1024**3, gt=0, description="Largest dataset upload [bytes] (whole multipart body)."
    )
    max_request_bytes: int = Field(
        1024**2, gt=0, description="Largest JSON request body [bytes] on every other route."
    )
    max_meta_bytes: int = Field(
        64 * 1024, gt=0, description="Largest `meta` form field of an upload [bytes]."
    )
    embedded_workers: int = Field(
        1, ge=1, description="Processes of the embedded runner (used without a broker)."
    )
    job_time_limit: float = Field(
        3000.0, gt=0, description="Hard wall-time limit of one job attempt [s]."
    )
    visibility_timeout: float = Field(
        3600.0,
        gt=0,
        description="Redis visibility timeout [s]: an unacknowledged task is redelivered "
        "after this long, so it must exceed job_time_limit.",
    )
    max_attempts: int = Field(
        2, ge=1, description="Attempts per job before a lost worker fails it for good."
    )
    lease_seconds: float = Field(
        30.0,
        gt=0,
        description="A running job whose worker has not renewed its lease for this long "
        "[s] is considered lost and re-queued (or failed after max_attempts).",
    )
    supervisor_interval: float = Field(
        5.0, gt=0, description="Period [s] of the API's check for lost jobs."
    )
    memory_limit_mb: float = Field(
        4096.0, gt=0, description="Identifications whose FNSI working memory estimate "
        "exceeds this [MiB] are refused with a message saying what to reduce.")
    requeue_after: float = Field(
        300.0, gt=0, description="A job still queued this long [s] after its message was "
        "published is published again (the broker may have lost it; duplicates are safe).")
    queue_name: str = Field("fnsi", description="Celery queue the API and workers share; "
                            "deployments sharing a Redis database need different names.")

    # -- job execution (issue 19: job processes, broker outages, requeue order) --------------
    job_nice: int = Field(
        10, ge=0, le=19, description="Niceness added to job processes (embedded runner and "
        "fnsi-worker pool), so the API on the same machine stays responsive while jobs "
        "compute; 0: the API's priority.", examples=[10])

    @field_validator("api_keys", mode="before")
    @classmethod
    def _split_keys(cls, value: object) -> object:
        if isinstance(value, str):
            return [k.strip() for k in value.split(",") if k.strip()]
        return value

    @model_validator(mode="after")
    def _time_limits_below_visibility(self) -> Settings:
        # A task still running when its message becomes visible again would run twice.
        if self.job_time_limit + 60 > self.visibility_timeout:
            raise ValueError(
                "FNSI_VISIBILITY_TIMEOUT must exceed FNSI_JOB_TIME_LIMIT by at least 60 s; "
                f"got {self.visibility_timeout} and {self.job_time_limit}"
            )
        return self

    @property
    def queue_kind(self) -> str:
        """``"celery"`` with a broker, else ``"embedded"``."""
        return "celery" if self.broker_url else "embedded"

    # -- issue 19, hostile uploads: what an upload may decode to (fnsi.formats.DecodeLimits)
    max_decoded_bytes: int = Field(
        512 * 1024**2, gt=0, description="Largest decoded dataset [bytes], samples counted as "
        "float64, computed from the file's headers before decoding (compressed uploads can "
        "decode a thousandfold); beyond it an upload is refused with 413. 512 MiB holds the "
        "paper's SmallSat record (40 channels x 240,000 samples, 77 MB) six times over; reading, "
        "summarising and storing a 500 MiB record peaked at 0.96 GiB.")
    max_channels: int = Field(
        1024, gt=0, description="Most channels (inputs plus outputs) of an uploaded dataset; "
        "beyond it an upload is refused with 413 before its samples are parsed.")
    # -- issue 19, HTTP layer: retention of finished jobs
    job_retention_days: float | None = Field(
        None, gt=0, description="Finished jobs (not those of a study) are deleted with their "
        "artefacts this many days [d] after they finished, by the API's supervisor. Unset: "
        "kept until deleted with DELETE /v1/jobs/{id}.", examples=[30])
    # -- issue 24, beyond one machine: records in PostgreSQL
    database_url: str | None = Field(
        None, description="Database of the job store's records, shared by every API and "
        "worker process (e.g. postgresql://fnsi@db.lab:5432/fnsi). Unset: SQLite in "
        "FNSI_DATA_DIR, for one machine.", examples=["postgresql://fnsi@127.0.0.1:5432/fnsi"])

    blob_store: Literal["folder", "database"] = Field(
        "folder", description="Where dataset blobs, job artefacts and study snapshots are "
        "kept: `folder`, "
        "only in FNSI_DATA_DIR (every API and worker must share it, e.g. over NFS); "
        "`database`, in the PostgreSQL database of FNSI_DATABASE_URL as well, so hosts need "
        "no shared folder (each one's FNSI_DATA_DIR is then its own cache).")

    @field_validator("database_url")
    @classmethod
    def _supported_database(cls, value: str | None) -> str | None:
        return None if value is None else check_database_url(value)


@lru_cache
def get_settings() -> Settings:
    """Settings of this process, read once from the environment."""
    return Settings()
