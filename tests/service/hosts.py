"""A deployment over several hosts for the tests: API and worker processes each on a data
folder of its own, sharing only a PostgreSQL server (records and blobs) and Redis.

The PostgreSQL server is private to the tests that use it (initdb in a temporary folder,
its own port), so that they can kill and restart it; without the server binaries those
tests are skipped, saying how to get them.
"""

from __future__ import annotations

import glob
import os
import shutil
import signal
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from itertools import count
from pathlib import Path

import httpx
import psycopg
import pytest

from tests.service.servers import Stack, free_port, service_env


def postgres_binaries() -> Path | None:
    """Folder of ``initdb`` and ``postgres``: on PATH, or Debian's /usr/lib/postgresql."""
    found = shutil.which("initdb")
    if found:
        return Path(found).parent
    versions = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb"))
    return Path(versions[-1]).parent if versions else None


@dataclass
class PrivatePostgres:
    """A PostgreSQL server of its own (trust auth on 127.0.0.1), killable and restartable."""

    folder: Path
    port: int
    binaries: Path
    process: subprocess.Popen | None = None

    @property
    def url(self) -> str:
        return f"postgresql://postgres@127.0.0.1:{self.port}/postgres"

    @classmethod
    def create(cls) -> PrivatePostgres:
        binaries = postgres_binaries()
        if binaries is None:
            pytest.skip("PostgreSQL server binaries (initdb, postgres) not found: install "
                        "them (Debian: apt-get install postgresql) to run the multi-host tests")
        # PostgreSQL refuses to run as root: the server then runs as the user postgres.
        folder = Path(tempfile.mkdtemp(prefix="pg_server_"))
        server = cls(folder, free_port(), binaries)
        if os.geteuid() == 0:
            shutil.chown(folder, "postgres")
        server._run([str(binaries / "initdb"), "-D", str(folder / "data"), "-A", "trust",
                     "-U", "postgres", "-E", "UTF8", "--no-sync"])
        return server

    def _run(self, command: list[str]) -> None:
        subprocess.run(command, check=True, capture_output=True, **self._as_owner())

    def _as_owner(self) -> dict:
        return {"user": "postgres"} if os.geteuid() == 0 else {}

    def start(self) -> None:
        """Start the server (recovering from a crash if it was killed) and wait for it."""
        # fsync off: only processes are killed here, never the machine, and the kernel
        # keeps what they wrote; it spares the shared disk of the test machine.
        self.process = subprocess.Popen(
            [str(self.binaries / "postgres"), "-D", str(self.folder / "data"), "-p",
             str(self.port), "-c", "listen_addresses=127.0.0.1", "-c",
             f"unix_socket_directories={self.folder}", "-c", "fsync=off", "-c",
             "max_connections=200"],
            stdout=subprocess.DEVNULL, stderr=open(self.folder / "server.log", "ab"),  # noqa: SIM115
            start_new_session=True, **self._as_owner())
        deadline = time.monotonic() + 60
        while True:
            try:
                psycopg.connect(self.url, connect_timeout=1).close()
                return
            except psycopg.OperationalError:
                assert self.process.poll() is None, (self.folder / "server.log").read_text()
                assert time.monotonic() < deadline, "PostgreSQL did not start"
                time.sleep(0.1)

    def kill(self) -> None:
        """SIGKILL the server and its backends, as a crash or an OOM kill would."""
        os.killpg(self.process.pid, signal.SIGKILL)
        self.process.wait()

    def remove(self) -> None:
        if self.process is not None and self.process.poll() is None:
            self.kill()
        shutil.rmtree(self.folder, ignore_errors=True)


class RoundRobin(httpx.BaseTransport):
    """Sends each request to the next API process in turn, as a load balancer in front
    of them would (the APIs' current addresses: a restarted API gets a new port)."""

    def __init__(self, apis: list[Stack]) -> None:
        self.apis, self.turn, self.inner = apis, count(), httpx.HTTPTransport()

    def handle_request(self, request: httpx.Request) -> httpx.Response:
        api = httpx.URL(self.apis[next(self.turn) % len(self.apis)].url)
        request.url = request.url.copy_with(host=api.host, port=api.port)
        request.headers["Host"] = f"{api.host}:{api.port}"
        return self.inner.handle_request(request)

    def close(self) -> None:
        self.inner.close()


@dataclass
class Deployment:
    """API processes and fnsi-worker processes, each host on its own data folder."""

    root: Path
    shared: dict[str, str]
    apis: list[Stack] = field(default_factory=list)
    workers: list[Stack] = field(default_factory=list)

    @property
    def env(self) -> dict[str, str]:
        return self.shared

    @property
    def url(self) -> str:
        return self.apis[0].url

    def host(self, name: str) -> Stack:
        data_dir = self.root / name / "data"
        data_dir.mkdir(parents=True)
        return Stack("", data_dir, service_env(data_dir, **self.shared), None)

    def add_api(self) -> Stack:
        api = self.host(f"api{len(self.apis)}")
        api.start_api()
        self.apis.append(api)
        return api

    def add_worker(self) -> Stack:
        worker = self.host(f"worker{len(self.workers)}")
        worker.start_worker(f"w{len(self.workers)}")
        self.workers.append(worker)
        return worker

    def client(self, **kwargs) -> httpx.Client:
        """A client of every API in turn (one address, several processes behind it)."""
        return httpx.Client(base_url=self.url, transport=RoundRobin(self.apis), timeout=30,
                            **kwargs)

    def worker_logs(self) -> str:
        return "".join(p.read_text() for w in self.workers
                       for p in w.data_dir.parent.glob("worker-*.log"))

    def stop(self) -> None:
        for host in [*self.workers, *self.apis]:
            host.stop()
