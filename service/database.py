"""The record database of the store: SQLite inside FNSI_DATA_DIR, or a PostgreSQL server
that API and worker processes on many hosts share (FNSI_DATABASE_URL).

Both go through one code path (SQLAlchemy Core, psycopg 3 for PostgreSQL); how each
dialect keeps the store's guarantees lives here, nowhere else:

* **Write transactions.** SQLite takes its one database lock at ``BEGIN IMMEDIATE``, so
  write transactions run one at a time. PostgreSQL runs them concurrently at READ
  COMMITTED; the store locks what it reads before deciding on it: existing rows with
  ``SELECT ... FOR UPDATE`` (ignored by SQLite, which needs none), keys that may have no
  row yet (a blob digest, an Idempotency-Key) with :meth:`Database.lock_key`, an advisory
  lock held to the end of the transaction (a no-op on SQLite).
* **Held locks** (:meth:`Database.held_lock`, e.g. a study's lock during a revision):
  ``flock`` on a file on SQLite, a session advisory lock on PostgreSQL; both end with the
  process that holds them (the kernel closes the file; the server ends the session of a
  dead client), so a killed worker never leaves a study locked.
* **Connections** are pooled per process; a forked child (Celery's pool) drops the pool it
  inherited and opens its own. PostgreSQL connections are checked before use, so a
  restarted server costs one failed request per stale connection at most.
"""

from __future__ import annotations

import fcntl
import hashlib
import os
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from sqlalchemy import Connection, Engine, create_engine, event, make_url, text
from sqlalchemy.exc import InterfaceError, OperationalError

from service.schema import migrate

# How often [s] a process waiting for a held lock tries again.
_LOCK_INTERVAL = 0.5
_engines: dict[tuple[str, int], Engine] = {}
_migrated: set[str] = set()


def sqlite_url(path: Path) -> str:
    """SQLAlchemy URL of the SQLite database file ``path``."""
    return f"sqlite:///{path}"


def _sqlite_engine(url: str) -> Engine:
    engine = create_engine(url, connect_args={"timeout": 30.0, "check_same_thread": False})

    @event.listens_for(engine, "connect")
    def _no_driver_transactions(dbapi_connection, _record) -> None:
        # The driver's own implicit BEGIN would be DEFERRED; the store begins itself.
        dbapi_connection.isolation_level = None
        # Readers never wait for the writer (persistent; set outside any transaction).
        dbapi_connection.execute("PRAGMA journal_mode=WAL")

    @event.listens_for(engine, "begin")
    def _begin(connection: Connection) -> None:
        write = connection.get_execution_options().get("fnsi_write", False)
        connection.exec_driver_sql("BEGIN IMMEDIATE" if write else "BEGIN")

    return engine


def _engine(url: str) -> Engine:
    """The pooled engine of ``url`` in this process."""
    key = (url, os.getpid())
    if key not in _engines:
        if url.startswith("sqlite:"):
            _engines[key] = _sqlite_engine(url)
        else:
            # psycopg 3 whatever driver the URL names; pre-ping survives a server restart.
            driver_url = url.split("://", 1)[1]
            _engines[key] = create_engine(f"postgresql+psycopg://{driver_url}",
                                          pool_pre_ping=True, pool_size=5, max_overflow=20)
    return _engines[key]


def _forget_inherited_engines() -> None:
    # A forked child must not use (nor close) its parent's connections.
    for engine in _engines.values():
        engine.dispose(close=False)
    _engines.clear()


os.register_at_fork(after_in_child=_forget_inherited_engines)


def close_database(url: str) -> None:
    """Close this process's pooled connections to ``url`` (a process that is done with a
    database, e.g. a test with a database of its own)."""
    engine = _engines.pop((url, os.getpid()), None)
    if engine is not None:
        engine.dispose()
    _migrated.discard(url)


def _lock_number(key: str) -> int:
    """Signed 64-bit number naming ``key`` for PostgreSQL's advisory locks."""
    return int.from_bytes(hashlib.sha256(key.encode()).digest()[:8], "big", signed=True)


def unreachable(err: BaseException) -> bool:
    """True if ``err`` says the database is out of reach (refused, restarting, connection
    lost), a condition that passes, rather than a fault of the statement."""
    return isinstance(err, OperationalError | InterfaceError)


def check_database_url(url: str) -> str:
    """``url`` if it names a database fnsi-service supports; else ValueError saying which."""
    if not url.startswith(("postgresql://", "postgresql+psycopg://", "postgres://",
                           "sqlite:///")):
        raise ValueError(f"FNSI_DATABASE_URL must start with postgresql:// (or sqlite:///); "
                         f"got {url.split('://', 1)[0]}://...")
    return url


class Database:
    """Connections and transactions of the store's records (schema migrated on first use).

    Parameters
    ----------
    url : str
        ``sqlite:///<file>`` or ``postgresql://user@host:port/database``.
    """

    def __init__(self, url: str) -> None:
        self.url = check_database_url(url)
        self.engine = _engine(self.url)
        self.dialect = self.engine.dialect.name
        if self.url not in _migrated:
            try:
                with self.transaction() as db:
                    self.lock_key(db, "schema")  # processes starting together migrate once
                    migrate(db)
            except OperationalError as err:
                shown = make_url(self.url).render_as_string(hide_password=True)
                raise RuntimeError(f"cannot open the database {shown} ({err.orig}); start "
                                   "it, or correct FNSI_DATABASE_URL") from err
            _migrated.add(self.url)

    @property
    def shared(self) -> bool:
        """True when processes on several hosts can share the database (PostgreSQL)."""
        return self.dialect == "postgresql"

    @contextmanager
    def read(self) -> Iterator[Connection]:
        """A connection for reads (one consistent snapshot on SQLite; rolled back after)."""
        with self.engine.connect() as db:
            yield db

    @contextmanager
    def transaction(self) -> Iterator[Connection]:
        """A write transaction, committed when the block ends, rolled back if it raises.

        On SQLite it holds the database lock from the start (no lost updates); on
        PostgreSQL lock what you read before deciding (see the module docstring).
        """
        with self.engine.connect() as db:
            db.execution_options(fnsi_write=True)
            with db.begin():
                yield db

    def lock_key(self, db: Connection, key: str) -> None:
        """Hold a lock named ``key`` until the transaction of ``db`` ends (PostgreSQL; on
        SQLite the transaction already holds the database lock)."""
        if self.dialect == "postgresql":
            db.execute(text("SELECT pg_advisory_xact_lock(:key)"), {"key": _lock_number(key)})

    @contextmanager
    def held_lock(self, key: str, file: Path, wait: Callable[[], None]) -> Iterator[None]:
        """Hold the lock ``key`` across processes and hosts while the block runs.

        Parameters
        ----------
        key : str
            Name of the lock (PostgreSQL).
        file : Path
            Lock file (SQLite: the processes share the data directory).
        wait : callable
            Called between tries; it may raise to give up (e.g. the job was cancelled).
        """
        if self.dialect == "postgresql":
            with self._advisory_lock(key, wait):
                yield
            return
        with open(file, "a") as handle:
            while not _try(lambda: fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)):
                wait()
                time.sleep(_LOCK_INTERVAL)
            try:
                yield
            finally:
                fcntl.flock(handle, fcntl.LOCK_UN)

    @contextmanager
    def _advisory_lock(self, key: str, wait: Callable[[], None]) -> Iterator[None]:
        number = {"key": _lock_number(key)}
        # A connection of its own, outside any transaction, kept while the lock is held. A
        # server restart ends the session and the lock with it: what the lock guards must
        # not rely on it alone (a study's snapshots are never overwritten, so a revision
        # that lost the lock cannot replace another's).
        with self.engine.connect() as db:
            db = db.execution_options(isolation_level="AUTOCOMMIT")
            while not db.execute(text("SELECT pg_try_advisory_lock(:key)"), number).scalar():
                wait()
                time.sleep(_LOCK_INTERVAL)
            try:
                yield
            finally:
                try:
                    db.execute(text("SELECT pg_advisory_unlock(:key)"), number)
                except Exception:
                    db.invalidate()  # never pool a session that may still hold the lock
                    raise


def _try(lock: Callable[[], None]) -> bool:
    try:
        lock()
    except BlockingIOError:
        return False
    return True
