"""The project installs as promised: console scripts, layering, container files."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = Path(sys.executable).parent


@pytest.mark.parametrize("script", ["fnsi", "fnsi-service", "fnsi-worker"])
def test_console_script_help_exits_zero(script: str) -> None:
    done = subprocess.run(
        [str(SCRIPTS / script), "--help"], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    assert "usage" in done.stdout.lower()


def test_fnsi_imports_without_the_service_layers() -> None:
    code = (
        "import sys, importlib, pkgutil, fnsi\n"
        "for info in pkgutil.iter_modules(fnsi.__path__):\n"
        "    importlib.import_module('fnsi.' + info.name)\n"
        "leaked = sorted(m for m in sys.modules if m.split('.')[0] in "
        "{'service', 'worker', 'fastapi', 'celery'})\n"
        "assert not leaked, leaked\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=300, cwd=ROOT)
    assert done.returncode == 0, done.stderr


def test_compose_runs_postgres_persistent_redis_and_scalable_apis_and_workers() -> None:
    compose = yaml.safe_load((ROOT / "docker-compose.yml").read_text())
    services = compose["services"]
    redis_command = " ".join(services["redis"]["command"])
    assert "--appendonly yes" in redis_command
    assert "--maxmemory-policy noeviction" in redis_command
    assert any(v.startswith("redis-data:") for v in services["redis"]["volumes"])
    assert any(v.startswith("postgres-data:") for v in services["postgres"]["volumes"])
    for name in ("api", "worker"):
        service = services[name]
        # `--scale api=N worker=M` fails on a fixed container name or a published port.
        assert "container_name" not in service and "ports" not in service
        # no shared folder: records and blobs in PostgreSQL
        assert "volumes" not in service
        env = service["environment"]
        assert env["FNSI_DATABASE_URL"].startswith("postgresql://")
        assert "@postgres:" in env["FNSI_DATABASE_URL"] and env["FNSI_BLOB_STORE"] == "database"
    assert services["proxy"]["ports"] == ["8000:8000"]
    assert set(compose["volumes"]) == {"redis-data", "postgres-data"}
