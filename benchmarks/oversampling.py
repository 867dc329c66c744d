"""Cost and effect of simulating identified models at a finer rate (`fnsi.oversampling`).

Times `fnsi.validation.compare` (the errors of a result) with the model simulated at fs
(``oversampling=1``, the old path) and with the automatic factor:

- ``chain_4``: the 4-DOF chain of ``tests/fnsi/test_oversampling.py`` with its stop at
  250 Hz (5 times the 50 Hz band edge, factor 4), 4 outputs; also the validation error
  over the noise floor either way;
- ``smallsat_3`` and ``smallsat_39``: the SmallSat ``single`` test (4 periods x 15,000
  samples at 2.5 kHz) with its true stop, 3 and 39 outputs. At 2.5 kHz the automatic
  factor is 1 (nothing changes); the time with factor 4 forced shows what the finer
  simulation would cost there.

Last output line: one JSON object, per case "factor", "at_fs_s", "automatic_s",
"forced_4_s" (SmallSat) and "ratio_at_fs", "ratio_automatic" (chain: largest NRMSE over
the noise floor of the channels).

Run: ``.venv/bin/python -m benchmarks.oversampling`` (about a minute).
"""

from __future__ import annotations

import json
import os
import sys
import time

import numpy as np

from fnsi.identification import IdentificationSettings, identify
from fnsi.nonlinear import NonlinearElement
from fnsi.oversampling import oversampling_factor
from fnsi.smallsat import simulate_preset
from fnsi.validation import compare
from tests.fnsi.conftest import chain_model, simulate

REPEATS = 3


def _timed(model, data, band_high: float, factor: int | None, discard: int):
    """Best of REPEATS wall times [s] of compare, and its errors."""
    best = np.inf
    for _ in range(REPEATS):
        start = time.perf_counter()
        errors = compare(model, data, discard_periods=discard, band_high=band_high,
                         oversampling=factor).errors
        best = min(best, time.perf_counter() - start)
    return round(best, 3), errors


def _chain() -> dict:
    band = (3.0, 50.0)
    stop = NonlinearElement("clearance", "d", gap=1e-3, coefficients=(3e4,))
    records = [simulate(chain_model(4, (stop,)), ["a"], fs=250.0, period=500,
                        periods=periods, band=band, rms=20.0, noise=0.005, seed=seed,
                        oversample=80) for periods, seed in ((8, 1), (4, 101))]
    model = identify(records[0], IdentificationSettings(
        band=band, order=8, block_rows=8,
        elements=(NonlinearElement("clearance", "d", gap=1e-3),))).model
    out = {"factor": oversampling_factor(model.elements, model.fs, band[1])}
    for name, factor in (("at_fs", 1), ("automatic", None)):
        seconds, errors = _timed(model, records[1], band[1], factor, 1)
        out[f"{name}_s"] = seconds
        out[f"ratio_{name}"] = round(float(np.max(errors.nrmse_percent
                                                  / errors.noise_floor_percent)), 3)
    return out


def _smallsat(data, outputs, block_rows: int, order: int) -> dict:
    stop = NonlinearElement("clearance", "NC2w_Z", "NC2b_Z", gap=1.5)
    model = identify(data, IdentificationSettings(
        band=(5.0, 50.0), block_rows=block_rows, order=order, max_order=max(order, 30),
        discard_periods=1, line_set="all", elements=(stop,), outputs=outputs,
        driving_points=((data.input_names[0], "NC2w_Z"),))).model
    out = {"factor": oversampling_factor(model.elements, model.fs, 50.0)}
    for name, factor in (("at_fs", 1), ("automatic", None), ("forced_4", 4)):
        out[f"{name}_s"] = _timed(model, data, 50.0, factor, 1)[0]
    return out


def main() -> int:
    if "OPENBLAS_NUM_THREADS" not in os.environ:
        # timings single-threaded, as in benchmarks/paper.py (read when numpy loads)
        os.environ["OPENBLAS_NUM_THREADS"] = "1"
        os.execv(sys.executable, [sys.executable, *sys.argv])
    summary = {"chain_4": _chain()}
    print("chain_4", summary["chain_4"], flush=True)
    data, _ = simulate_preset("single", periods=4, samples_per_period=15_000, seed=2)
    for name, case in (("smallsat_3", (("NC2w_Z", "NC2b_Z", "W_Z"), 60, 8)),
                       ("smallsat_39", (None, 20, 18))):
        summary[name] = _smallsat(data, *case)
        print(name, summary[name], flush=True)
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
