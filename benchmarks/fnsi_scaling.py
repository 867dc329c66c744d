"""Wall time of each FNSI stage and peak memory on synthetic data (docs/design.md section 5).

Synthetic periodic records shaped like the paper's workloads: 8 periods of 30,000 samples
at 2.5 kHz (2 discarded), 3,240 lines in 5-50 Hz, the response of a random 9-mode linear
structure plus 0.5 % output noise. The nonlinear elements are evaluated on the outputs
like real ones (their true coefficients are zero: only the cost is of interest here).
Each case runs :func:`fnsi.identification.identify` in a fresh process, so the reported
peak resident memory [MiB] belongs to that case alone (interpreter included).

Run: ``.venv/bin/python benchmarks/fnsi_scaling.py [--threads N]`` (N BLAS threads per
case; default: the library's choice). The machine's load average is printed before and
after: BLAS threads compete badly with other processes, so compare numbers taken on an
idle machine; with ``--threads 1`` the CPU time column is a load-independent estimate of
the single-core wall time. The compiled basis kernels are loaded before timing, as in a long-lived
worker process. The last line is one JSON object
{"single39_s", "single3_s", "multi18_s", "multi18_peak_mb"}: the total identification time
of the single-39, single-3 and multi-18 (automatic block rows) cases and the peak memory
of multi-18 at the largest block-row count its periodic signal allows (i = 15).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import resource
import time

import numpy as np

FS, PERIOD, PERIODS, BAND = 2500.0, 30000, 8, (5.0, 50.0)


def synthetic_measurement(n_outputs: int, seed: int = 0):
    """Periodic force at output 0 and the response of a random 9-mode structure."""
    from fnsi.measurement import Measurement

    rng = np.random.default_rng(seed)
    f = np.fft.rfftfreq(PERIOD, 1 / FS)
    lines = (f >= BAND[0]) & (f < BAND[1])
    U = np.zeros(f.size, dtype=complex)
    U[lines] = np.exp(2j * np.pi * rng.random(lines.sum()))
    fn = np.linspace(8.0, 45.0, 9)
    poles = -0.02 * 2 * np.pi * fn + 2j * np.pi * fn
    shapes = rng.standard_normal((9, n_outputs))
    shapes[:, 0] = 1.0  # driving point at output 0, every mode excited
    s = 2j * np.pi * f[:, None]
    modal = 1 / (s - poles) - 1 / (s - poles.conj())
    Y = (modal * U[:, None]) @ (shapes * shapes[:, :1] / (2j * poles.imag[:, None]))
    u = np.fft.irfft(U, n=PERIOD)
    y = np.fft.irfft(Y, n=PERIOD, axis=0)
    u, y = np.tile(u, PERIODS), np.tile(y, (PERIODS, 1))
    y += 0.005 * y.std(axis=0) * rng.standard_normal(y.shape)
    names = [f"y{k}" for k in range(n_outputs)]
    return Measurement.from_arrays(u / u.std(), y / u.std(), FS, input_names=["y0"],
                                   output_names=names, periods=PERIODS)


def elements_for(n_outputs: int, n_splines: int):
    """One cubic spring (n_splines = 0) or n_splines 9-interval splines on output pairs."""
    from fnsi.nonlinear import NonlinearElement

    if n_splines == 0:
        return (NonlinearElement("polynomial", "y0", "y1", exponent=3.0),)
    return tuple(NonlinearElement("spline", f"y{2 * k}", f"y{2 * k + 1}", intervals=9)
                 for k in range(n_splines))


def run_case(case: dict, threads: int | None) -> dict:
    """Identify one case; returns its stage timings and peak memory."""
    if threads is not None:  # before numpy is imported in this fresh process
        for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
            os.environ[var] = str(threads)
    from fnsi.identification import IdentificationSettings, identify

    data = synthetic_measurement(case["outputs"])
    for element in elements_for(case["outputs"], case["splines"]):  # load compiled kernels
        element.resolve(np.array([-1.0, 1.0])).basis(np.zeros(2), np.zeros(2))
    settings = IdentificationSettings(
        band=BAND, block_rows=case["block_rows"], order=case["order"], max_order=60,
        discard_periods=2, elements=elements_for(case["outputs"], case["splines"]))
    start, cpu = time.perf_counter(), time.process_time()
    result = identify(data, settings)
    total, cpu = time.perf_counter() - start, time.process_time() - cpu
    return {"name": case["name"], "timings": result.timings, "total_s": total, "cpu_s": cpu,
            "lines": int(result.coefficients[0].frequencies.size),
            "extended_inputs": int(result.model.B.shape[1]),
            "block_rows": int(result.settings.block_rows),
            "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


CASES = [
    dict(name="single39", outputs=39, block_rows=50, order=18, splines=0),
    dict(name="single3", outputs=3, block_rows=100, order=8, splines=0),
    # the paper's i = 50 is refused for periodic data (the elimination of E_i would take
    # every harmonic line): the automatic count, and the largest count accepted
    dict(name="multi18", outputs=18, block_rows="auto", order=10, splines=8),
    dict(name="multi18_i15", outputs=18, block_rows=15, order=10, splines=8),
    dict(name="single18_i100", outputs=18, block_rows=100, order=18, splines=0),
]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=None, help="BLAS threads per case")
    threads = parser.parse_args().threads
    context = multiprocessing.get_context("spawn")
    print(f"load average before: {os.getloadavg()[0]:.1f} (2 cores); BLAS threads: "
          f"{threads or 'default'}")
    rows = []
    for case in CASES:
        with context.Pool(1) as pool:
            rows.append(pool.apply(run_case, (case, threads)))
    print(f"load average after: {os.getloadavg()[0]:.1f}")
    stages = list(rows[0]["timings"])
    print(f"{'case':<15}{'lines':>6}{'q':>4}{'i':>5}" + "".join(f"{s[:13]:>15}" for s in stages)
          + f"{'total s':>10}{'cpu s':>8}{'peak MiB':>10}")
    for r in rows:
        print(f"{r['name']:<15}{r['lines']:>6}{r['extended_inputs']:>4}{r['block_rows']:>5}"
              + "".join(f"{r['timings'].get(s, 0.0):>15.3f}" for s in stages)
              + f"{r['total_s']:>10.2f}{r['cpu_s']:>8.2f}{r['peak_mb']:>10.0f}")
    by_name = {r["name"]: r for r in rows}
    print(json.dumps({"single39_s": round(by_name["single39"]["total_s"], 3),
                      "single3_s": round(by_name["single3"]["total_s"], 3),
                      "multi18_s": round(by_name["multi18"]["total_s"], 3),
                      "multi18_peak_mb": round(by_name["multi18_i15"]["peak_mb"], 1)}))


if __name__ == "__main__":
    main()
