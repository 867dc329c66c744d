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


def test_compose_runs_persistent_redis_and_scalable_workers() -> None:
    compose = yaml.safe_load((ROOT / "docker-compose.yml").read_text())
    services = compose["services"]
    redis_command = " ".join(services["redis"]["command"])
    assert "--appendonly yes" in redis_command
    assert "--maxmemory-policy noeviction" in redis_command
    assert any(v.startswith("redis-data:") for v in services["redis"]["volumes"])
    worker = services["worker"]
    # `--scale worker=N` fails on a fixed container name or a published port.
    assert "container_name" not in worker and "ports" not in worker
    data_volume = "fnsi-data:/data"
    assert data_volume in worker["volumes"] and data_volume in services["api"]["volumes"]
    assert set(compose["volumes"]) == {"redis-data", "fnsi-data"}
