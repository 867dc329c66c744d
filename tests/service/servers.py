"""Real processes for end-to-end tests: fnsi-service (uvicorn) and fnsi-worker (Celery)."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import urlsplit, urlunsplit

import httpx
import redis

BIN = Path(sys.executable).parent
TEST_REDIS_DB = 15


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def redis_test_url() -> str:
    """The Redis of FNSI_REDIS_URL, database 15 (flushed by the tests that use it)."""
    parts = urlsplit(os.environ.get("FNSI_REDIS_URL", "redis://127.0.0.1:6379/0"))
    return urlunsplit(parts._replace(path=f"/{TEST_REDIS_DB}"))


def service_env(data_dir: Path, **extra: str) -> dict[str, str]:
    """Environment of a service or worker process: no inherited FNSI_* but the Redis URL."""
    env = {k: v for k, v in os.environ.items()
           if not k.startswith("FNSI_") or k == "FNSI_REDIS_URL"}
    # A queue per stack: stacks share the test Redis database.
    env.update(FNSI_DATA_DIR=str(data_dir), FNSI_LEASE_SECONDS="3",
               FNSI_QUEUE_NAME=f"fnsi-test-{data_dir.parent.name}",
               FNSI_SUPERVISOR_INTERVAL="0.5")
    env.update(extra)  # may name another queue, e.g. one for several hosts
    return env


@dataclass
class Stack:
    """An API server (and its workers) sharing one data dir."""

    url: str
    data_dir: Path
    env: dict[str, str]
    api: subprocess.Popen | None
    workers: list[subprocess.Popen] = field(default_factory=list)
    logs: Path | None = None

    def client(self, **kwargs) -> httpx.Client:
        return httpx.Client(base_url=self.url, timeout=30, **kwargs)

    def start_api(self) -> None:
        """Start fnsi-service on a free port (own process group) and wait for /health."""
        port = free_port()
        log = open(self.data_dir.parent / "api.log", "ab")  # noqa: SIM115
        self.api = subprocess.Popen([str(BIN / "fnsi-service"), "--port", str(port)],
                                    env=self.env, stdout=log, stderr=subprocess.STDOUT,
                                    start_new_session=True)
        self.url = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + 60
        while True:
            try:
                if httpx.get(f"{self.url}/health", timeout=1).status_code == 200:
                    return
            except httpx.TransportError:
                pass
            if self.api.poll() is not None or time.monotonic() > deadline:
                self.stop()
                raise RuntimeError(f"fnsi-service did not start; see {log.name}")
            time.sleep(0.1)

    def kill_api(self) -> None:
        """SIGKILL the API and its embedded runner processes, as a crash would."""
        os.killpg(self.api.pid, signal.SIGKILL)
        self.api.wait()

    def start_worker(self, name: str) -> subprocess.Popen:
        log = open(self.data_dir.parent / f"worker-{name}.log", "ab")  # noqa: SIM115
        worker = subprocess.Popen(
            [str(BIN / "fnsi-worker"), "--concurrency", "1", "--hostname", f"{name}@%h",
             "--loglevel", "INFO"], env=self.env, stdout=log, stderr=subprocess.STDOUT,
            start_new_session=True)
        self.workers.append(worker)
        return worker

    def kill_worker(self, worker: subprocess.Popen) -> None:
        """SIGKILL the worker and its pool children (its whole process group)."""
        os.killpg(worker.pid, signal.SIGKILL)
        worker.wait()
        self.workers.remove(worker)

    def stop(self) -> None:
        for worker in list(self.workers):
            os.killpg(worker.pid, signal.SIGTERM)
            try:
                worker.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(worker.pid, signal.SIGKILL)
                worker.wait()
        if self.api is None or self.api.poll() is not None:
            return
        self.api.terminate()
        try:
            self.api.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.api.kill()
            self.api.wait()


def start_stack(data_dir: Path, *, broker_url: str | None = None, workers: int = 0,
                **extra: str) -> Stack:
    """Start fnsi-service (and ``workers`` fnsi-worker processes); wait for /health."""
    data_dir.mkdir(parents=True, exist_ok=True)
    env = service_env(data_dir, **({"FNSI_BROKER_URL": broker_url} if broker_url else {}),
                      **extra)
    stack = Stack("", data_dir, env, None)
    stack.start_api()
    for k in range(workers):
        stack.start_worker(f"w{k}")
    return stack


@contextmanager
def celery_stack(data_dir: Path) -> Iterator[Stack]:
    """fnsi-service and one fnsi-worker on the test Redis, its database flushed around."""
    url = redis_test_url()
    broker = redis.Redis.from_url(url)
    broker.flushdb()
    stack = start_stack(data_dir, broker_url=url, workers=1)
    try:
        yield stack
    finally:
        stack.stop()
        broker.flushdb()


def wait_for_job(client: httpx.Client, job_id: str, timeout: float = 240,
                 states=("succeeded", "failed", "cancelled")) -> dict:
    """Poll a job until it reaches one of ``states``."""
    deadline = time.monotonic() + timeout
    while True:
        job = client.get(f"/v1/jobs/{job_id}").json()
        if job["state"] in states:
            return job
        if time.monotonic() > deadline:
            raise AssertionError(f"job {job_id} still {job['state']} after {timeout} s: {job}")
        time.sleep(0.2)


def wait_for_progress(client: httpx.Client, job_id: str, fraction: float,
                      timeout: float = 60) -> None:
    """Poll a job until it is running with at least ``fraction`` done."""
    deadline = time.monotonic() + timeout
    while (job := client.get(f"/v1/jobs/{job_id}").json())["progress"] < fraction:
        assert job["state"] in ("queued", "running"), job
        assert time.monotonic() < deadline, job
        time.sleep(0.1)
