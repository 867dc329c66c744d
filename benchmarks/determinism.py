"""Benchmark: do the headline numbers depend on the machine? (issue 20, determinism)

Three workloads, each run in a fresh subprocess under every OpenBLAS kernel type
(``OPENBLAS_CORETYPE`` Haswell, SkylakeX, Zen, Sandybridge) with 1 and 2 BLAS threads
on one noise realisation, and under the default kernel on several noise realisations:

* ``single3``: the SmallSat single test on a short record (3 periods of 2,500 samples,
  outputs NC2w_Z, NC2b_Z, W_Z, band 5-50 Hz = 2 % of fs, i = 20, automatic order; the
  service's end-to-end test): order, first two modes, clearance coefficient.
* ``refined``: a 3-DOF chain with a stiff stop (5 % output noise, automatic block rows,
  i = 84 on 22 % of fs), identified at order 6 and refined by its simulation error
  (:mod:`fnsi.refinement`): FNSI coefficient, refined validation error on an independent
  record.
* ``study``: a 5-DOF chain with a hidden cubic spring at x3; the diagnosis of a linear
  revision (:meth:`fnsi.study.Study.diagnose`): the element it chooses, its coefficient
  and its validation error.

For every number it prints the spread (max - min) over the 8 machine configurations,
the spread over the noise realisations and their ratio, which must stay below 0.1; a
chosen element, and whether each workload ran or failed, must be the same in every
configuration. The table goes to
``benchmarks/results/determinism.md``; the last output line is one JSON object
{"rows": [{"number", "machine_spread", "noise_spread", "ratio"}...], "max_ratio",
"same_choices", "passed"}.

Run: ``.venv/bin/python benchmarks/determinism.py [--seeds 4]`` (about ten minutes on a
quiet machine; the kernels a CPU lacks fall back to ones it has, so on a CPU without
AVX-512 the SkylakeX rows repeat another kernel).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

KERNELS = ("Haswell", "SkylakeX", "Zen", "Sandybridge")
THREADS = (1, 2)
RESULTS = Path(__file__).parent / "results" / "determinism.md"
LIMIT = 0.1
"""Largest allowed ratio of the machine spread to the noise spread (issue 20)."""


# -- the workloads, run in the worker subprocess ------------------------------------------------
def single3(seed: int) -> dict:
    from fnsi.identification import IdentificationSettings, identify
    from fnsi.nonlinear import NonlinearElement
    from fnsi.smallsat import simulate_preset

    data, _ = simulate_preset("single", periods=3, samples_per_period=2500, seed=seed,
                              outputs=("NC2w_Z", "NC2b_Z", "W_Z"))
    stop = NonlinearElement("clearance", "NC2w_Z", "NC2b_Z", gap=1.5)
    result = identify(data, IdentificationSettings(band=(5.0, 50.0), block_rows=20,
                                                   max_order=20, elements=(stop,)))
    modes = result.modal
    return {"single3 order": result.order,
            "single3 f1 [Hz]": modes.frequencies[0], "single3 zeta1 [%]":
            100 * modes.damping_ratios[0], "single3 f2 [Hz]": modes.frequencies[1],
            "single3 mu": result.coefficients[0].mean_real}


def _chain(elements, diagonal: list[float], beta: float, dashpot: float = 0.0):
    """Chain x1, x2, ... of unit masses and 10 kN/m couplings, ``diagonal`` the stiffness
    diagonal in units of 10 kN/m, damping 1.0 M + beta K plus a dashpot at x1 [N s/m]."""
    from fnsi.structure import StructuralModel

    n = len(diagonal)
    stiffness = 1e4 * (np.diag(diagonal) - np.eye(n, k=1) - np.eye(n, k=-1))
    damping = np.eye(n) + beta * stiffness
    damping[0, 0] += dashpot
    return StructuralModel(np.eye(n), damping, stiffness,
                           tuple(f"x{j + 1}" for j in range(n)), tuple(elements))


def _record(structure, seed: int, rms: float, noise: float, fs: float, period: int,
            band: tuple[float, float]):
    from fnsi.acquisition import acquire
    from fnsi.excitation import Excitation, periodic_noise

    signal = periodic_noise(period, fs, band, rms, seed=seed)
    return acquire(structure, Excitation.at_dof(signal, fs, "x1"), fs=fs, fs_int=8 * fs,
                   periods=4, noise_percent=noise, discard_periods=1, seed=seed + 100)[0]


def refined(seed: int) -> dict:
    from fnsi.identification import IdentificationSettings, identify
    from fnsi.nonlinear import NonlinearElement
    from fnsi.validation import compare

    stop = NonlinearElement("clearance", "x3", "x2", gap=1e-4, coefficients=(3e4,))
    structure = _chain((stop,), [2.0, 2.0, 2.0], 6e-4, dashpot=1.0)   # 12-29 Hz
    estimation, validation = (_record(structure, 2 * seed + s, 1.0, 5.0, 200.0, 2000,
                                      (3.0, 45.0)) for s in (1, 2))
    unknown = NonlinearElement("clearance", "x3", "x2", gap=1e-4)
    result = identify(estimation, IdentificationSettings(
        band=(3.0, 45.0), order=6, elements=(unknown,), refine=True))
    errors = compare(result.model, validation, discard_periods=1, band_high=45.0).errors
    return {"refined block rows": result.settings.block_rows,
            "refined mu": result.coefficients[0].mean_real,
            "refined validation [%]": errors.overall_percent}


def study(seed: int) -> dict:
    from fnsi.diagnosis import DiagnosisSettings
    from fnsi.identification import IdentificationSettings
    from fnsi.nonlinear import NonlinearElement
    from fnsi.study import Study

    cubic = NonlinearElement("polynomial", "x3", exponent=3.0, coefficients=(2e8,))
    structure = _chain((cubic,), [3.0, 3.0, 3.0, 3.0, 2.0], 2e-4)    # 16-34 Hz
    data = [_record(structure, 2 * seed + s, 20.0, 0.5, 1000.0, 2500, (5.0, 60.0))
            for s in (1, 2)]
    settings = IdentificationSettings(band=(5.0, 60.0), block_rows=15, order=10,
                                      max_order=20, driving_points=(("F_x1", "x1"),))
    diagnosis = Study.create(*data, settings).diagnose(
        settings=DiagnosisSettings(validated_candidates=3, curve_locations=1))
    top = diagnosis.candidates[0]
    location = f"{top.effect.value} at {top.location.dof}" + (
        f"-{top.location.ref}" if top.location.ref else "")
    return {"study choice": location,
            "study mu": top.element.coefficients[0] if top.element else float("nan"),
            "study validation [%]": top.validation_nrmse_percent}


WORKLOADS = (single3, refined, study)


def worker(seed: int) -> None:
    """Print one JSON object of every workload's numbers; a workload that raises gives
    its error's type as "<workload> outcome" (a machine-dependent failure is a result)."""
    out: dict = {}
    for workload in WORKLOADS:
        try:
            found = workload(seed)
        except Exception as error:  # any failure is a result here
            out[f"{workload.__name__} outcome"] = f"failed: {type(error).__name__}"
            continue
        out[f"{workload.__name__} outcome"] = "ran"
        out.update({k: (v if isinstance(v, str) else float(v)) for k, v in found.items()})
    print(json.dumps(out))


# -- the driver -------------------------------------------------------------------------------
def run(seed: int, kernel: str | None, threads: int) -> dict:
    env = dict(os.environ, OPENBLAS_NUM_THREADS=str(threads))
    env.pop("OPENBLAS_CORETYPE", None)
    if kernel is not None:
        env["OPENBLAS_CORETYPE"] = kernel
    done = subprocess.run([sys.executable, __file__, "--worker", "--seed", str(seed)],
                          env=env, capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def spread(values: list) -> float:
    return float(np.max(values) - np.min(values))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=4, help="noise realisations")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--seed", type=int, default=0, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        worker(args.seed)
        return 0
    machine = {}
    for kernel in KERNELS:
        for threads in THREADS:
            machine[f"{kernel} x{threads}"] = run(0, kernel, threads)
            print(f"{kernel}, {threads} thread(s): {machine[f'{kernel} x{threads}']}",
                  flush=True)
    noise = [machine["Haswell x1"]] + [run(seed, "Haswell", 1)
                                       for seed in range(1, args.seeds)]
    for seed, found in enumerate(noise):
        print(f"noise realisation {seed}: {found}", flush=True)
    rows, choices = [], {}
    names = dict.fromkeys(k for found in [*machine.values(), *noise] for k in found)
    for name in names:
        if any(isinstance(found.get(name), str) for found in noise):
            choices[name] = (sorted({str(m.get(name)) for m in machine.values()}),
                             sorted({str(n.get(name)) for n in noise}))
            continue
        # a number missing from a run whose workload failed: the outcome row shows it
        m_spread = spread([m[name] for m in machine.values() if name in m])
        n_spread = spread([n[name] for n in noise if name in n])
        ratio = 0.0 if m_spread == 0 else m_spread / n_spread if n_spread else float("inf")
        rows.append({"number": name, "machine_spread": m_spread, "noise_spread": n_spread,
                     "ratio": ratio})
    same = all(len(m) == 1 for m, _ in choices.values())
    max_ratio = max(r["ratio"] for r in rows)
    table = ["| number | spread over 4 kernels x 2 thread counts | spread over "
             f"{args.seeds} noise realisations | ratio |", "|---|---|---|---|"]
    table += [f"| {r['number']} | {r['machine_spread']:.3g} | {r['noise_spread']:.3g} | "
              f"{r['ratio']:.2g} |" for r in rows]
    table += [f"| {name} | {' / '.join(m)} | {' / '.join(n)} | "
              f"{'same' if len(m) == 1 else 'DIFFERS'} |" for name, (m, n) in choices.items()]
    print("\n".join(table))
    RESULTS.write_text(
        "# Determinism: headline numbers across BLAS kernels and threads\n\n"
        "Written by `benchmarks/determinism.py` (workloads in its docstring). Machine "
        "spread: max - min over OPENBLAS_CORETYPE Haswell, SkylakeX, Zen, Sandybridge "
        "with 1 and 2 BLAS threads on noise realisation 0; noise spread: max - min over "
        f"{args.seeds} realisations under Haswell, 1 thread. Issue 20 asks for a ratio "
        f"below {LIMIT}; a chosen element must not depend on the machine.\n\n"
        + "\n".join(table) + "\n\nThe numbers, not the run time, are the result: the "
        "last run was on a 2-core AMD EPYC with AVX-512 (all four kernel types available) "
        "shared with other jobs.\n")
    passed = same and max_ratio < LIMIT
    print(json.dumps({"rows": rows, "max_ratio": max_ratio, "same_choices": same,
                      "passed": passed}))
    return 0 if passed else 1


if __name__ == "__main__":
    sys.exit(main())
