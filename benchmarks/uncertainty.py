"""Cost of the standard deviations (:mod:`fnsi.uncertainty`) in an identification.

Two workloads, each identified with ``uncertainty=False`` and ``True`` (best of
``--repeat`` interleaved runs each, single-threaded BLAS unless OPENBLAS_NUM_THREADS is
set):

``smallsat``
    The paper's SmallSat single record (100 N at NC2w_Z, 8 periods of 30,000 samples at
    2.5 kHz, 39 outputs, 0.5 % noise; simulated once, about 20 s) with the single-39
    settings of ``benchmarks/paper.py``: the NC2-Z clearance with its gap, i = 50, all
    3,240 lines, noise weighting, warping, automatic order.
``chain``
    A 3-DOF chain with a cubic spring at x1 (1 % output noise, 6 periods of 4,000
    samples at 400 Hz, one transient period), automatic order and block rows.

Target (issue 23): the uncertainty adds at most 50 % to the identification's time.
Last output line: one JSON object per workload name with the times [s], the ratio and the
first mode's frequency with its standard deviation.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import time

import numpy as np

from fnsi.acquisition import acquire
from fnsi.excitation import Excitation, multisine
from fnsi.identification import IdentificationSettings, identify
from fnsi.nonlinear import NonlinearElement
from fnsi.smallsat import AXIAL_GAP, simulate_preset
from fnsi.structure import StructuralModel


def smallsat():
    """The single record and the single-39 settings."""
    measurement, _ = simulate_preset("single")
    stop = NonlinearElement("clearance", "NC2w_Z", "NC2b_Z", gap=AXIAL_GAP)
    return measurement, IdentificationSettings(
        band=(5.0, 50.0), block_rows=50, order="auto", max_order=60, discard_periods=2,
        elements=(stop,), driving_points=(("F_NC2w_Z", "NC2w_Z"),), weighting=True,
        line_set="all", frequency_warping=True)


def chain():
    """A 3-DOF chain (10 kN/m springs, unit masses, 12-29 Hz) with a cubic spring at x1."""
    cubic = NonlinearElement("polynomial", "x1", exponent=3.0, coefficients=(1e9,))
    stiffness = 1e4 * (np.diag([2.0, 2.0, 2.0]) - np.eye(3, k=1) - np.eye(3, k=-1))
    structure = StructuralModel(np.eye(3), np.eye(3) + 6e-4 * stiffness, stiffness,
                                ("x1", "x2", "x3"), (cubic,))
    fs = 400.0
    force = multisine(4000, fs, (3.0, 45.0), 70.0, seed=1)
    measurement, _ = acquire(structure, Excitation.at_dof(force, fs, "x1"), fs=fs,
                             fs_int=8 * fs, periods=6, noise_percent=1.0, discard_periods=1)
    return measurement, IdentificationSettings(
        band=(3.0, 45.0), discard_periods=1, max_order=20,
        elements=(dataclasses.replace(cubic, coefficients=None),))


def timed(measurement, settings, repeat: int):
    """Best wall times [s] of ``repeat`` identifications without and with the standard
    deviations, interleaved (the machine's load then weighs on both alike), and the last
    result with them."""
    variants = (dataclasses.replace(settings, uncertainty=False), settings)
    best, result = [float("inf")] * 2, None
    for _ in range(repeat):
        for k, variant in enumerate(variants):
            start = time.perf_counter()
            result = identify(measurement, variant)
            best[k] = min(best[k], time.perf_counter() - start)
    return best, result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3, help="timed runs per variant (3)")
    parser.add_argument("--workloads", nargs="+", default=["chain", "smallsat"],
                        choices=["chain", "smallsat"])
    args = parser.parse_args()
    summary = {}
    for name in args.workloads:
        measurement, settings = {"chain": chain, "smallsat": smallsat}[name]()
        (without, with_), result = timed(measurement, settings, args.repeat)
        u = result.uncertainty
        summary[name] = {
            "order": result.order, "without_s": round(without, 3), "with_s": round(with_, 3),
            "uncertainty_stage_s": round(result.timings["uncertainty"], 3),
            "added_percent": round(100 * (with_ / without - 1), 1),
            "f1_hz": round(float(result.modal.frequencies[0]), 4),
            "f1_std_hz": float(f"{u.frequencies[0]:.3g}"),
            "zeta1_std": float(f"{u.damping_ratios[0]:.3g}"),
            "mu": [float(f"{c.mean_real:.6g}") for c in result.coefficients],
            "mu_std": [float(f"{s:.3g}") for s in u.coefficients]}
        print(name, summary[name], flush=True)
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
