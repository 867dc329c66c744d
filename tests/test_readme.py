"""The README's Quick start and curl session, run as written, checked by what they print.

The server is started by the Quick start's own command, ``make run``, from the
repository, with ``VENV`` naming the virtual environment this test runs in and its
install marker taken as up to date (``make -o``): ``make run`` on a fresh clone would
create and install ``.venv`` first, which ``make test`` (how the suite is run) has just
done for this environment, and reinstalling inside a test would need the network. The
curl session, the README's fenced block, is then run verbatim by ``sh`` (dash) and by
``bash`` in an empty folder whose ``.venv`` is that environment, so its files
(``single.npz``, the PNG, the report) land there and not in the repository.

Both run in a network namespace of their own (``unshare``): the session talks to the
fixed address ``127.0.0.1:8000``, which other programs on the machine may hold.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
VENV = Path(sys.prefix)
# Bring up loopback, start the server as the Quick start does, wait for it, run the
# session; every process of the group stops when the driver ends.
DRIVER = r"""
stop() { status=$?; trap '' TERM; kill 0; exit $status; }
trap stop EXIT
ip link set lo up
make -C "$ROOT" -o "$VENV/.installed" run VENV="$VENV" > "$WORK/server.log" 2>&1 &
tries=0
until curl -sf http://127.0.0.1:8000/health > /dev/null; do
  tries=$((tries + 1)); [ $tries -gt 600 ] && { echo "no server" >&2; exit 97; }; sleep 0.1
done
cd "$WORK" && "$SHELL_UNDER_TEST" session.sh
"""


def fenced_block(after: str) -> tuple[str, str]:
    """The language and text of the first fenced block after the line ``after``."""
    text = (ROOT / "README.md").read_text()
    start = text.index(after)
    match = re.compile(r"^```(\w*)\n(.*?)^```", re.S | re.M).search(text, start)
    return match[1], match[2]


def namespace() -> list[str] | None:
    """The command prefix of a private network namespace, or None if there is none."""
    for prefix in (["unshare", "-n"], ["unshare", "-rn"]):
        if shutil.which("unshare") and subprocess.run(
                [*prefix, "true"], capture_output=True).returncode == 0:
            return prefix
    return None


def test_the_quick_start_is_make_run_and_make_test():
    language, block = fenced_block("## Quick start")
    commands = [line.split("#")[0].strip() for line in block.splitlines() if line.strip()]
    assert language == "bash" and commands == ["make run", "make test"]


@pytest.mark.parametrize("shell", ["sh", "bash"])
def test_the_curl_session_runs_as_written(shell, tmp_path):
    prefix = namespace()
    if prefix is None:
        pytest.skip("no network namespace (unshare -n) to give the session its fixed port")
    language, session = fenced_block("A whole session with curl")
    assert language == "sh"
    (tmp_path / "session.sh").write_text(session)
    (tmp_path / ".venv").symlink_to(VENV)
    env = {**os.environ, "ROOT": str(ROOT), "VENV": str(VENV), "WORK": str(tmp_path),
           "SHELL_UNDER_TEST": shutil.which(shell), "FNSI_DATA_DIR": str(tmp_path / "data")}
    env = {k: v for k, v in env.items() if not k.startswith("FNSI_") or k == "FNSI_DATA_DIR"}
    driver = subprocess.Popen([*prefix, "sh", "-c", DRIVER], env=env, text=True,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              start_new_session=True)
    try:
        out, err = driver.communicate(timeout=600)
    finally:
        if driver.poll() is None:
            os.killpg(driver.pid, signal.SIGKILL)
            driver.wait()
    log = (tmp_path / "server.log").read_text() if (tmp_path / "server.log").exists() else ""
    assert driver.returncode == 0, f"{out}\n{err}\n{log}"
    check_printed(out, tmp_path)
    assert "interactive API docs at http://127.0.0.1:8000/docs" in log


def check_printed(out: str, folder: Path) -> None:
    """What the session prints: the files written, the dataset, the progress in percent,
    the result, the artefacts, and the two downloads."""
    assert "wrote single.npz and single.truth.json" in out
    objects = [json.loads(m) for m in re.findall(r"^\{.*?^\}", out, re.S | re.M)]
    dataset, result = objects
    assert dataset == {"fs": 2500.0, "samples": 7500, "periods": 3, "inputs": ["F_NC2w_Z"],
                       "outputs": 39}
    progress = re.findall(r"^(queued|running) (\d+) % ", out, re.M)
    assert progress and all(0 <= int(p) <= 100 for _, p in progress)
    assert result["state"] == "succeeded" and result["error"] is None, result
    assert result["order"] >= 2 and result["modes_hz"]
    assert all(5 <= f <= 50 for f in result["modes_hz"])
    (stop,) = result["coefficients"]
    assert stop["name"].startswith("clearance") and stop["mean_real"] > 0
    names = set(re.findall(r"^([\w.-]+\.(?:png|json|npz|html|uff|mat))$", out, re.M))
    assert {"stabilisation.png", "result.json", "model.npz", "report.html"} <= names
    # issue 20: the session ends with a model that simulates (its error and errors.png),
    # or with the warning that says why not, printed by the session's own command
    if isinstance(result["model_error"], float):
        assert "errors.png" in names and result["model_error"] > 0
    else:
        assert result["warnings"] and "errors.png" not in names, result
    assert re.search(r"^stabilisation\.png:\s+PNG image data", out, re.M)
    assert re.search(r"^report\.html:\s+HTML document", out, re.M)
    assert (folder / "report.html").read_text().startswith("<!DOCTYPE html>")
