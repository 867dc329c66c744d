"""Speed of the output-error refinement (`fnsi.refinement.refine`) on the SmallSat.

The `single` test (100 N RMS at NC2w_Z, 8 periods x 30,000 samples at 2.5 kHz, 0.5 %
output noise) is identified by FNSI with its true stop (clearance NC2w_Z-NC2b_Z, gap
known, contact stiffness identified), then refined, once with the paper's three
single-3 channels and once with all 39 outputs. Settings follow the diagnosis benchmark
(`benchmarks/diagnosis.py`): the excited lines, i = 20 and order 18 for 39 outputs, i = 60
and order 8 for three. The stages that dominate are printed from a profile of the run.

Last output line: one JSON object {"outputs_3": {...}, "outputs_39": {...}} with, per
case, "refine_s", "steps", "initial_pct", "final_pct" (simulation error on the estimation
data) and "per_step_s".

Run: ``.venv/bin/python benchmarks/refinement.py`` (about two minutes).
"""

from __future__ import annotations

import cProfile
import json
import os
import pstats
import sys
import time

from fnsi.identification import IdentificationSettings, identify
from fnsi.nonlinear import NonlinearElement
from fnsi.refinement import refine
from fnsi.smallsat import simulate_preset

THREE = ("NC2w_Z", "NC2b_Z", "W_Z")
CASES = {"outputs_3": (THREE, 60, 8), "outputs_39": (None, 20, 18)}
"""Case name -> (outputs, block rows, order)."""


def _case(outputs, block_rows: int, order: int, data) -> dict:
    stop = NonlinearElement("clearance", "NC2w_Z", "NC2b_Z", gap=1.5)
    settings = IdentificationSettings(
        band=(5.0, 50.0), block_rows=block_rows, order=order, max_order=max(order, 30),
        discard_periods=2, line_set="excited", elements=(stop,), outputs=outputs,
        driving_points=((data.input_names[0], "NC2w_Z"),))
    model = identify(data, settings).model
    profile = cProfile.Profile()
    start = time.perf_counter()
    profile.enable()
    refinement = refine(model, data, discard_periods=2, band_high=50.0)
    profile.disable()
    elapsed = time.perf_counter() - start
    print(f"{model.n_outputs} outputs, order {order}: {refinement.summary}")
    pstats.Stats(profile).sort_stats("tottime").print_stats(6)
    return {"refine_s": round(elapsed, 2), "steps": refinement.iterations,
            "initial_pct": refinement.initial_percent, "final_pct": refinement.final_percent,
            "per_step_s": round(elapsed / max(refinement.iterations, 1), 3)}


def main() -> int:
    if "OPENBLAS_NUM_THREADS" not in os.environ:
        # timings single-threaded, as in benchmarks/paper.py (read when numpy loads)
        os.environ["OPENBLAS_NUM_THREADS"] = "1"
        os.execv(sys.executable, [sys.executable, *sys.argv])
    data, _ = simulate_preset("single", periods=8, samples_per_period=30_000,
                              noise_percent=0.5, seed=1)
    summary = {name: _case(*case, data) for name, case in CASES.items()}
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
