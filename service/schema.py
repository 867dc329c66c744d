"""Tables of the store's records and their migrations (SQLite and PostgreSQL alike).

The schema carries a version (table ``schema_version``). A new database is created at
:data:`VERSION` from the tables below; an older one is brought to it by the steps of
:data:`_STEPS`, each in the transaction that checks the version, so processes starting
together migrate once and a failed step leaves the previous version intact.

A small versioned table rather than Alembic: the store migrates itself when a process
opens it (no operator step between an upgrade and a restart), the steps are a few
statements each, and the schema is defined once, here, for both dialects.

Versions:

1. The SQLite store before versioning (datasets ordered by SQLite's rowid, study jobs
   found by reading their request JSON).
2. Datasets get an explicit sequence number (PostgreSQL has no rowid; SQLite keeps the
   old rowids, so cursors handed out before stay valid); jobs get an indexed ``study_id``
   column; ``store_info`` holds the store's identity; ``objects`` lists the blobs and
   artefacts kept in the database (:mod:`service.objects`).
"""

from __future__ import annotations

from collections.abc import Callable

from sqlalchemy import (
    BigInteger,
    Boolean,
    Column,
    Connection,
    Double,
    ForeignKey,
    Index,
    Integer,
    MetaData,
    Table,
    Text,
    UniqueConstraint,
    inspect,
    select,
)

VERSION = 2
STUDY_JOB_KINDS = ("study", "study_revision", "study_diagnosis")
"""Job kinds acting on a study: creation (revision 0), a revision, a diagnosis."""

# Sequence numbers: SQLite's AUTOINCREMENT needs exactly INTEGER PRIMARY KEY.
_SEQ = BigInteger().with_variant(Integer(), "sqlite")

metadata = MetaData()

blobs = Table(
    "blobs", metadata,
    Column("digest", Text, primary_key=True),
    Column("summary", Text, nullable=False),
    Column("size", BigInteger, nullable=False))

uploads = Table(
    "uploads", metadata,
    Column("upload_key", Text, primary_key=True),
    Column("digest", Text, ForeignKey("blobs.digest"), nullable=False))

datasets = Table(
    "datasets", metadata,
    Column("seq", _SEQ, primary_key=True, autoincrement=True),
    Column("id", Text, unique=True, nullable=False),
    Column("owner", Text, nullable=False),
    Column("digest", Text, ForeignKey("blobs.digest"), nullable=False),
    Column("name", Text, nullable=False),
    Column("source_job", Text),
    Column("created_at", Text, nullable=False),
    Index("datasets_by_owner", "owner"),
    sqlite_autoincrement=True)

jobs = Table(
    "jobs", metadata,
    Column("seq", _SEQ, primary_key=True, autoincrement=True),
    Column("id", Text, unique=True, nullable=False),
    Column("owner", Text, nullable=False),
    Column("kind", Text, nullable=False),
    Column("state", Text, nullable=False),
    Column("progress", Double, nullable=False, server_default="0"),
    Column("message", Text, nullable=False, server_default=""),
    Column("request", Text, nullable=False),
    Column("result", Text),
    Column("error", Text),
    Column("created_at", Text, nullable=False),
    Column("started_at", Text),
    Column("finished_at", Text),
    Column("attempts", Integer, nullable=False, server_default="0"),
    Column("lease_until", Double),
    Column("cancel_requested", Boolean, nullable=False, server_default="0"),
    Column("batch_id", Text),
    Column("enqueued_at", Double),
    Column("study_id", Text),
    Index("jobs_by_owner", "owner", "seq"),
    Index("jobs_by_state", "state"),
    Index("jobs_by_finish", "finished_at"),
    Index("jobs_by_study", "study_id"),
    sqlite_autoincrement=True)

batches = Table(
    "batches", metadata,
    Column("id", Text, primary_key=True),
    Column("owner", Text, nullable=False),
    Column("idempotency_key", Text),
    Column("request_hash", Text, nullable=False),
    Column("job_ids", Text, nullable=False),
    Column("created_at", Text, nullable=False),
    UniqueConstraint("owner", "idempotency_key"))

store_info = Table(
    "store_info", metadata,
    Column("key", Text, primary_key=True),
    Column("value", Text, nullable=False))

objects = Table(
    "objects", metadata,
    Column("key", Text, primary_key=True),
    Column("oid", BigInteger, nullable=False),  # a PostgreSQL large object
    Column("size", BigInteger, nullable=False))

schema_version = Table(
    "schema_version", metadata,
    Column("version", Integer, nullable=False))


def _to_2(db: Connection) -> None:
    """Version 1 (SQLite only) to 2: rebuild ``datasets`` with ``seq`` = the old rowid."""
    db.exec_driver_sql("ALTER TABLE datasets RENAME TO datasets_v1")
    db.exec_driver_sql("DROP INDEX IF EXISTS datasets_by_owner")
    datasets.create(db)
    db.exec_driver_sql("INSERT INTO datasets (seq, id, owner, digest, name, source_job, "
                       "created_at) SELECT rowid, id, owner, digest, name, source_job, "
                       "created_at FROM datasets_v1")
    db.exec_driver_sql("DROP TABLE datasets_v1")
    db.exec_driver_sql("ALTER TABLE jobs ADD COLUMN study_id TEXT")
    kinds = ", ".join(f"'{kind}'" for kind in STUDY_JOB_KINDS)
    db.exec_driver_sql(f"UPDATE jobs SET study_id = json_extract(request, '$.study_id') "
                       f"WHERE kind IN ({kinds})")
    db.exec_driver_sql("CREATE INDEX jobs_by_study ON jobs (study_id)")
    store_info.create(db)
    objects.create(db)


_STEPS: dict[int, Callable[[Connection], None]] = {2: _to_2}


def migrate(db: Connection) -> None:
    """Create the schema, or bring it to :data:`VERSION` (inside the caller's transaction,
    which holds the schema lock)."""
    tables = set(inspect(db).get_table_names())
    if "jobs" not in tables:
        metadata.create_all(db)
        db.execute(schema_version.insert().values(version=VERSION))
        return
    if "schema_version" in tables:
        version = db.execute(select(schema_version.c.version)).scalar_one()
    else:
        schema_version.create(db)
        db.execute(schema_version.insert().values(version=1))
        version = 1
    if version > VERSION:
        raise RuntimeError(f"the store's schema is version {version}, newer than this "
                           f"fnsi-service ({VERSION}); upgrade fnsi-service")
    for step in range(version + 1, VERSION + 1):
        _STEPS[step](db)
        db.execute(schema_version.update().values(version=step))
