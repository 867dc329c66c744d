"""Benchmark: time of one diagnosis on the 5-DOF chains of issue 21 (target: 5 s).

The chains the issue describes: random masses (0.5-2 kg) and springs (5-20 kN/m, both
ends grounded), Rayleigh damping of 1-4 % at the first mode, a force at one end, five
displacement outputs with 0.5 % noise, fs = 256 Hz, a 3-50 Hz random-phase multisine of
6 periods (one discarded). One cubic spring between two neighbouring DOFs is hidden,
its coefficient set so that its force reaches half the linear spring's at the RMS
relative displacement of the linear response (a clear, not a dominant, nonlinearity).
Data come from the library's acquisition (Newmark at 8 x fs): what is measured is the
time a user waits, not the diagnosis' accuracy (that is ``generalisation.py --part
hidden``, with its own integrator).

The study is created as a user would, with the band alone (order ``"auto"``), and
diagnosed with the default :class:`fnsi.diagnosis.DiagnosisSettings`. Prints one line per
chain (times, top candidate, truth); the last line is one JSON object::

    {"chains", "median_create_s", "median_diagnosis_s", "max_diagnosis_s", "top1_correct"}

Run: ``OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/diagnosis_chain.py [--chains 5]``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from fnsi.acquisition import acquire
from fnsi.excitation import Excitation, multisine
from fnsi.identification import IdentificationSettings
from fnsi.nonlinear import NonlinearElement
from fnsi.structure import StructuralModel
from fnsi.study import Study, law_name

NAMES = ("x1", "x2", "x3", "x4", "x5")
FS = 256.0               # Hz
PERIOD = 1024            # samples: 0.25 Hz lines, 188 of them in the band
BAND = (3.0, 50.0)       # Hz
PERIODS = 6
NOISE_PERCENT = 0.5
FORCE_RMS = 10.0         # N
CUBIC_SHARE = 0.5        # cubic force / linear spring force at the RMS relative motion


def draw_chain(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Masses, stiffness and Rayleigh damping matrices of a random grounded chain."""
    n = len(NAMES)
    m = np.diag(rng.uniform(0.5, 2.0, n))
    springs = rng.uniform(5e3, 2e4, n + 1)                 # ground, n - 1 couplings, ground
    k = np.diag(springs[:-1] + springs[1:])
    k -= np.diag(springs[1:-1], 1) + np.diag(springs[1:-1], -1)
    omega = np.sqrt(np.sort(np.linalg.eigvals(np.linalg.solve(m, k)).real))
    zeta = rng.uniform(0.01, 0.04)
    # alpha M + beta K with the same damping ratio at the first and last modes
    beta = 2 * zeta / (omega[0] + omega[-1])
    return m, k, beta * omega[0] * omega[-1] * m + beta * k


def measure(model: StructuralModel, excitation: Excitation, seed: int):
    """One noisy record of ``model`` (the user's data)."""
    measurement, _ = acquire(model, excitation, fs=FS, fs_int=8 * FS, periods=PERIODS,
                             noise_percent=NOISE_PERCENT, discard_periods=1, seed=seed)
    return measurement


def hidden_cubic(m, c, k, excitation, rng) -> NonlinearElement:
    """A cubic spring between random neighbours, sized on the linear response."""
    j = int(rng.integers(len(NAMES) - 1))
    linear = StructuralModel(m, c, k, NAMES, ())
    record, _ = acquire(linear, excitation, fs=FS, fs_int=8 * FS, periods=2,
                        noise_percent=0.0, discard_periods=1)
    relative = record.y[0, -PERIOD:, j + 1] - record.y[0, -PERIOD:, j]
    k3 = CUBIC_SHARE * -k[j, j + 1] / np.mean(relative ** 2)
    return NonlinearElement("polynomial", NAMES[j + 1], NAMES[j], exponent=3.0,
                            coefficients=(k3,))


def run_chain(seed: int) -> dict:
    """Create and diagnose the study of one random chain; its times and answer."""
    rng = np.random.default_rng(seed)
    m, k, c = draw_chain(rng)
    signals = [multisine(PERIOD, FS, BAND, FORCE_RMS, seed=seed * 10 + r) for r in (1, 2)]
    excitations = [Excitation.at_dof(s, FS, NAMES[0]) for s in signals]
    cubic = hidden_cubic(m, c, k, excitations[0], rng)
    model = StructuralModel(m, c, k, NAMES, (cubic,))
    estimation, validation = (measure(model, e, seed * 10 + r)
                              for r, e in enumerate(excitations))
    start = time.perf_counter()
    study = Study.create(estimation, validation, IdentificationSettings(band=BAND))
    create_s = time.perf_counter() - start
    start = time.perf_counter()
    diagnosis = study.diagnose()
    diagnosis_s = time.perf_counter() - start
    top = diagnosis.candidates[0] if diagnosis.candidates else None
    element = None if top is None else top.element
    label = "none" if element is None else law_name(element)
    # the location either way round: a spring between x2 and x3 is one between x3 and x2
    correct = element is not None and label.split()[:2] == ["cubic", "spring"] and (
        {element.dof, element.ref} == {cubic.dof, cubic.ref})
    return {"seed": seed, "create_s": create_s, "diagnosis_s": diagnosis_s,
            "top": label, "truth": law_name(cubic), "correct": correct,
            "stages": diagnosis.timings,
            "nrmse_pct": study.revisions[0].nrmse_percent,
            "floor_pct": study.noise_floor_percent}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--chains", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0, help="first chain's seed")
    args = parser.parse_args()
    results = []
    for seed in range(args.seed, args.seed + args.chains):
        r = run_chain(seed)
        results.append(r)
        print(f"chain {seed}: create {r['create_s']:.1f} s, diagnosis {r['diagnosis_s']:.1f} s;"
              f" revision 0 {r['nrmse_pct']:.3g} % (floor {r['floor_pct']:.3g} %); top "
              f"{r['top']}, truth {r['truth']}")
        print("  stages [s]: " + ", ".join(f"{k} {v:.1f}" for k, v in r["stages"].items()))
    diagnosis = [r["diagnosis_s"] for r in results]
    print(json.dumps({"chains": len(results),
                      "median_create_s": round(float(np.median([r["create_s"]
                                                                for r in results])), 2),
                      "median_diagnosis_s": round(float(np.median(diagnosis)), 2),
                      "max_diagnosis_s": round(max(diagnosis), 2),
                      "top1_correct": sum(r["correct"] for r in results)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
