"""The hostile-input catalogue's machinery: a real fnsi-service with two API keys, a seeded
tenant, a fingerprint of everything stored, and one keep-alive HTTP connection per case.

Every case of ``tests/service/hostile/`` is checked by :func:`check_refused`: the status,
a ``problem+json`` detail that names the fault, stored data byte-identical before and
after, and a next request answered normally on the *same* TCP connection (a server that
raises drops its keep-alive connection, which costs well-behaved clients their request).
"""

from __future__ import annotations

import hashlib
import http.client
import json
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import httpx
import pytest

from tests.service import formats
from tests.service.servers import Stack, start_stack, wait_for_job

OWNER, INTRUDER = "hostile-owner", "hostile-intruder"
PROBLEM = "application/problem+json"
REC = formats.make_record()  # fs 1000 Hz, 4 periods x 500 samples, force -> NC2w_Z, NC2b_Z
# A small identification of the record that finishes in seconds.
IDENTIFY = {"band": [5.0, 100.0], "block_rows": 10, "max_order": 10}


@dataclass(frozen=True)
class Reply:
    """An HTTP response read off a raw connection."""

    status: int
    headers: dict[str, str]
    content: bytes

    @property
    def text(self) -> str:
        return self.content.decode(errors="replace")

    def json(self) -> Any:
        return json.loads(self.content)


class Connection:
    """One HTTP/1.1 keep-alive connection, requests built by httpx (JSON, forms, files).

    ``http.client`` reuses the socket while the server keeps it open, so
    :meth:`assert_kept` can tell a kept connection from a dropped one.
    """

    def __init__(self, url: str, key: str | None = OWNER) -> None:
        parts = urlsplit(url)
        self.url = url
        self.key = key
        self.http = http.client.HTTPConnection(parts.hostname, parts.port, timeout=120)

    def __enter__(self) -> Connection:
        return self

    def __exit__(self, *exc: object) -> None:
        self.http.close()

    def request(self, method: str, path: str, **kwargs: Any) -> Reply:
        """Send ``method path`` (httpx keyword arguments: json, data, files, content,
        headers, params) with this connection's key and read the whole reply."""
        headers = dict(kwargs.pop("headers", {}) or {})
        if self.key is not None:
            headers.setdefault("X-API-Key", self.key)
        built = httpx.Request(method, self.url + path, headers=headers, **kwargs)
        body = built.read()
        target = built.url.raw_path.decode()
        wire = {k: v for k, v in built.headers.items() if k.lower() != "host"}
        self.http.request(method, target, body=body or None, headers=wire)
        response = self.http.getresponse()
        content = response.read()
        return Reply(response.status, {k.lower(): v for k, v in response.getheaders()},
                     content)

    def get(self, path: str, **kwargs: Any) -> Reply:
        return self.request("GET", path, **kwargs)

    def post(self, path: str, **kwargs: Any) -> Reply:
        return self.request("POST", path, **kwargs)

    def assert_kept(self) -> None:
        """The server kept this connection open and answers the next request on it."""
        socket = self.http.sock
        assert socket is not None, "the server closed the connection after that reply"
        reply = self.get("/health")
        assert reply.status == 200, reply.text
        assert self.http.sock is socket, "the next request needed a new connection"


@dataclass(frozen=True)
class Seeded:
    """The running stack and what the owner holds on it: one dataset, one finished job."""

    stack: Stack
    dataset_id: str
    job_id: str

    def connect(self, key: str | None = OWNER) -> Connection:
        return Connection(self.stack.url, key)


def npz_bytes(**changes: Any) -> bytes:
    """The record's canonical NPZ with arrays replaced (None removes one)."""
    return formats.npz_bytes(REC, **changes)


def settle(stack: Stack, timeout: float = 240) -> None:
    """Wait until neither tenant has a queued or running job, so fingerprints hold still."""
    deadline = time.monotonic() + timeout
    with httpx.Client(base_url=stack.url, timeout=30) as client:
        for key in (OWNER, INTRUDER):
            for state in ("queued", "running"):
                while client.get("/v1/jobs", params={"state": state, "limit": 1},
                                 headers={"X-API-Key": key}).json()["items"]:
                    assert time.monotonic() < deadline, f"{key} still has {state} jobs"
                    time.sleep(0.2)


def fingerprint(stack: Stack) -> dict[str, Any]:
    """Everything a refused request must leave alone: every stored file's digest (records
    are compared through the API, the SQLite files change with checkpoints) and what each
    tenant's listings say."""
    root = stack.data_dir
    files = sorted((str(p.relative_to(root)), hashlib.sha256(p.read_bytes()).hexdigest())
                   for p in root.rglob("*")
                   if p.is_file() and not p.name.startswith("fnsi.sqlite3"))
    listings = {}
    with httpx.Client(base_url=stack.url, timeout=30) as client:
        for key in (OWNER, INTRUDER):
            for route in ("/v1/datasets", "/v1/jobs", "/v1/studies"):
                reply = client.get(route, params={"limit": 100}, headers={"X-API-Key": key})
                listings[key, route] = reply.json()
    return {"files": files, "listings": listings}


def api_rss_bytes(stack: Stack) -> int:
    """Resident memory of the API process [bytes], from /proc (Linux)."""
    status = Path(f"/proc/{stack.api.pid}/status").read_text()
    line = next(x for x in status.splitlines() if x.startswith("VmRSS:"))
    return int(line.split()[1]) * 1024


def check_refused(seeded: Seeded, send: Callable[[Connection], Reply], status: int,
                  says: tuple[str, ...], key: str | None = OWNER) -> Reply:
    """Send a hostile request and check the catalogue's four promises (module docstring)."""
    settle(seeded.stack)
    before = fingerprint(seeded.stack)
    with seeded.connect(key) as connection:
        reply = send(connection)
        assert reply.status == status, reply.text
        assert reply.headers.get("content-type") == PROBLEM, reply.headers
        problem = reply.json()
        assert problem["status"] == status
        for words in says:
            assert words.lower() in problem["detail"].lower(), problem["detail"]
        connection.assert_kept()
    settle(seeded.stack)
    assert fingerprint(seeded.stack) == before
    return reply


def start_hostile_stack(data_dir: Path, **extra: str) -> Stack:
    """fnsi-service on its embedded runner with the two tenants' keys."""
    return start_stack(data_dir, FNSI_API_KEYS=f"{OWNER},{INTRUDER}", **extra)


def seed(stack: Stack) -> Seeded:
    """Upload the record as the owner and run one small identification of it."""
    with httpx.Client(base_url=stack.url, timeout=60, headers={"X-API-Key": OWNER}) as client:
        created = client.post("/v1/datasets", files={"file": ("rec.npz", npz_bytes())})
        assert created.status_code == 201, created.text
        dataset_id = created.json()["id"]
        job = client.post("/v1/identifications", json={"dataset_id": dataset_id, **IDENTIFY})
        assert job.status_code == 202, job.text
        wait_for_job(client, job.json()["id"])
    return Seeded(stack, dataset_id, job.json()["id"])


@pytest.fixture(scope="package")
def seeded(tmp_path_factory) -> Iterator[Seeded]:
    """One hostile stack for the whole catalogue, seeded once."""
    stack = start_hostile_stack(tmp_path_factory.mktemp("hostile") / "data")
    try:
        yield seed(stack)
    finally:
        stack.stop()
