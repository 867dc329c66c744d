"""Shared objects: dataset blobs, job artefacts and study snapshots that every host
reaches, kept in the PostgreSQL database of the records as large objects
(FNSI_BLOB_STORE=database).

Without it the data directory is the only copy, so hosts must share it. With it the data
directory of each host becomes a cache: the store writes a file there as before, then
copies it into an object in the same transaction as the record that names it, so an
object is whole or absent, and a record never names an object that was not committed.
Objects are written once per key (a dataset blob's key is its content digest); an
artefact written again by a new attempt of its job replaces the object whole.

Large objects rather than ``bytea`` rows: they are read and written in chunks, so a
dataset of hundreds of megabytes never sits whole in the memory of the API or of the
database server.
"""

from __future__ import annotations

import os
from pathlib import Path

from sqlalchemy import Connection, delete, insert, select, text

from service.schema import objects

_CHUNK = 4 * 1024 * 1024  # bytes per round trip; large enough that latency does not count


class DatabaseObjects:
    """Named immutable objects in PostgreSQL large objects (table ``objects``)."""

    def put(self, db: Connection, key: str, path: Path) -> None:
        """Store the file ``path`` as object ``key`` in the transaction of ``db``
        (replacing an object of that key)."""
        self.delete(db, [key])
        oid = db.execute(text("SELECT lo_create(0)")).scalar_one()
        with open(path, "rb") as file:
            offset = 0
            while chunk := file.read(_CHUNK):
                db.execute(text("SELECT lo_put(CAST(:oid AS oid), :offset, :data)"),
                           {"oid": oid, "offset": offset, "data": chunk})
                offset += len(chunk)
        db.execute(insert(objects).values(key=key, oid=oid, size=offset))

    def fetch(self, db: Connection, key: str, path: Path) -> bool:
        """Write object ``key`` to the new file ``path``; False if there is no such object."""
        found = db.execute(select(objects.c.oid, objects.c.size).where(objects.c.key == key)
                           ).first()
        if found is None:
            return False
        with open(path, "wb") as file:
            for offset in range(0, found.size, _CHUNK):
                file.write(db.execute(text("SELECT lo_get(CAST(:oid AS oid), :offset, :n)"),
                                      {"oid": found.oid, "offset": offset, "n": _CHUNK}
                                      ).scalar_one())
            file.flush()
            os.fsync(file.fileno())
        return True

    def listing(self, db: Connection, prefix: str) -> list[tuple[str, int]]:
        """(key without ``prefix``, size in bytes) of the objects under ``prefix``."""
        rows = db.execute(select(objects.c.key, objects.c.size)
                          .where(objects.c.key.startswith(prefix, autoescape=True)))
        return [(key[len(prefix):], size) for key, size in rows]

    def delete(self, db: Connection, keys: list[str]) -> None:
        """Remove the objects ``keys`` (those that exist) in the transaction of ``db``."""
        oids = db.execute(select(objects.c.oid).where(objects.c.key.in_(keys))).scalars().all()
        for oid in oids:
            db.execute(text("SELECT lo_unlink(CAST(:oid AS oid))"), {"oid": oid})
        db.execute(delete(objects).where(objects.c.key.in_(keys)))

    def delete_under(self, db: Connection, prefix: str) -> None:
        """Remove every object under ``prefix``."""
        self.delete(db, [prefix + name for name, _ in self.listing(db, prefix)])
