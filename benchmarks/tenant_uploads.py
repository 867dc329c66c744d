"""Does an upload's time tell a tenant what another tenant holds? And CSV download times.

Starts fnsi-service (embedded runner) with two API keys, A and B. Each round A uploads a
fresh record (4 x ``--period`` samples of three channels: 24 MB as NPZ by default); then B
uploads the same file ("held": A holds it) and another fresh record ("fresh": nobody holds
it), in alternating order from round to round. With a
deduplication cache shared across tenants B's "held" upload skipped parsing and was ~3x
faster than "fresh", so B could test whether A holds a given file; with blobs addressed
per tenant the two take the same path and the ratio is ~1. Then A downloads its record as
CSV twice: the first download renders the CSV, the second streams the kept rendering.

Last output line: one JSON object {"rounds", "held_median_s", "fresh_median_s",
"held_over_fresh", "csv_first_median_s", "csv_kept_median_s"}.

Run from the repository root (it reuses the test suite's server helpers):
``.venv/bin/python -m benchmarks.tenant_uploads`` (a few minutes).
"""

from __future__ import annotations

import argparse
import io
import json
import statistics
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np

from tests.service import formats
from tests.service.servers import start_stack

KEYS = ("tenant-a", "tenant-b")


def record_npz(seed: int, period: int) -> bytes:
    """A fresh record (its noise depends on ``seed``) as an NPZ file."""
    record = formats.make_record(periods=4, period_length=period, seed=seed)
    buffer = io.BytesIO()
    np.savez(buffer, u=record.u, y=record.y, fs=np.float64(record.fs),
             input_names=np.array(record.input_names),
             output_names=np.array(record.output_names), periods=np.int64(record.periods))
    return buffer.getvalue()


def timed(client: httpx.Client, method: str, path: str, **kwargs) -> tuple[float, httpx.Response]:
    start = time.perf_counter()
    response = client.request(method, path, **kwargs)
    elapsed = time.perf_counter() - start
    assert response.status_code < 300, response.text
    return elapsed, response


def run(rounds: int, period: int) -> dict[str, float]:
    with tempfile.TemporaryDirectory() as folder:
        stack = start_stack(Path(folder) / "data", FNSI_API_KEYS=",".join(KEYS))
        try:
            a, b = (httpx.Client(base_url=stack.url, timeout=300, headers={"X-API-Key": k})
                    for k in KEYS)
            held, fresh, csv_first, csv_kept = [], [], [], []
            for k in range(rounds):
                data, new = record_npz(k, period), record_npz(1000 + k, period)
                _, ours = timed(a, "POST", "/v1/datasets", files={"file": ("r.npz", data)})
                replies = {}
                for name in ("held", "fresh") if k % 2 == 0 else ("fresh", "held"):
                    replies[name] = timed(b, "POST", "/v1/datasets", files={
                        "file": ("r.npz", data if name == "held" else new)})
                held.append(replies["held"][0])
                fresh.append(replies["fresh"][0])
                for _, response in replies.values():  # B must not deduplicate with itself
                    timed(b, "DELETE", f"/v1/datasets/{response.json()['id']}")
                download = f"/v1/datasets/{ours.json()['id']}/download"
                csv_first.append(timed(a, "GET", download, params={"format": "csv"})[0])
                csv_kept.append(timed(a, "GET", download, params={"format": "csv"})[0])
                print(f"round {k}: held {held[-1]:.3f} s, fresh {fresh[-1]:.3f} s, csv "
                      f"{csv_first[-1]:.3f} s then {csv_kept[-1]:.3f} s", flush=True)
        finally:
            stack.stop()
    return {"rounds": rounds, "held_median_s": statistics.median(held),
            "fresh_median_s": statistics.median(fresh),
            "held_over_fresh": statistics.median(held) / statistics.median(fresh),
            "csv_first_median_s": statistics.median(csv_first),
            "csv_kept_median_s": statistics.median(csv_kept)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=6, help="upload rounds (default 6)")
    parser.add_argument("--period", type=int, default=250_000,
                        help="samples per period of the records (default 250000)")
    args = parser.parse_args()
    print(json.dumps(run(args.rounds, args.period)))


if __name__ == "__main__":
    main()
