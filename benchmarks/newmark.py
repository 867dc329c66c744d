"""Speed of the nonlinear Newmark integrator and of the `single` SmallSat acquisition.

Prints the integration rate (steps per second), the wall time of the full `single` preset
(8 periods x 30,000 samples at 2.5 kHz integrated at 20 kHz: 1.92 million steps, then
decimation and noise), and compares the per-step cost with a flop count for the model
size. Uses ``fnsi.smallsat.simulate_preset("single")`` when it exists, else a random
model of 60 DOFs with 8 clearance stops driven like the preset.

Last output line: one JSON object {"single_preset_s", "steps_per_s", "n_dofs"}.

Run: ``.venv/bin/python benchmarks/newmark.py``
"""

from __future__ import annotations

import json
import time

import numpy as np
import scipy.stats

from fnsi.acquisition import acquire, upsample
from fnsi.excitation import Excitation, periodic_noise
from fnsi.newmark import NewmarkIntegrator
from fnsi.nonlinear import NonlinearElement
from fnsi.structure import StructuralModel

FS, FS_INT, SAMPLES, PERIODS, OUTPUTS = 2500.0, 20000.0, 30000, 8, 39


def random_model(r: int = 60, stops: int = 8, seed: int = 0) -> StructuralModel:
    """Unit-mass model with modes log-spaced in 8 Hz - 2 kHz, non-proportional damping and
    ``stops`` clearance elements between DOF pairs, gaps at 1.5 x the linear RMS."""
    rng = np.random.default_rng(seed)
    Q = scipy.stats.ortho_group.rvs(r, random_state=rng)
    omega = 2 * np.pi * np.geomspace(8.0, 2000.0, r)
    K = Q @ np.diag(omega**2) @ Q.T
    C = Q @ np.diag(0.04 * omega) @ Q.T
    for i, j in rng.choice(r, size=(6, 2), replace=False):  # lumped dashpots
        C[[i, j, i, j], [i, j, j, i]] += [20.0, 20.0, -20.0, -20.0]
    names = tuple(f"d{k}" for k in range(r))
    excitation = preset_excitation(names)
    U = np.fft.rfft(excitation.u[0, :, 0])
    w = 2 * np.pi * np.fft.rfftfreq(SAMPLES, 1 / FS)[: U.size]
    lines = np.flatnonzero(np.abs(U) > 0)
    H = np.linalg.solve(-(w[lines, None, None] ** 2) + 1j * w[lines, None, None] * C + K,
                        np.eye(r)[:, :1])[:, :, 0]
    elements = []
    for e in range(stops):
        rel = H[:, 2 * e] - H[:, 2 * e + 1]
        rms = np.sqrt(2 * np.sum(np.abs(rel * U[lines]) ** 2)) / SAMPLES
        elements.append(NonlinearElement("clearance", names[2 * e], names[2 * e + 1],
                                         gap=1.5 * rms, coefficients=(10 * K[2 * e, 2 * e],)))
    return StructuralModel(np.eye(r), C, K, names, tuple(elements))


def preset_excitation(names: tuple[str, ...]) -> Excitation:
    """Periodic noise in 5-50 Hz, 100 N RMS on the first DOF (the `single` preset's kind)."""
    return Excitation.at_dof(periodic_noise(SAMPLES, FS, (5.0, 50.0), 100.0), FS, names[0])


def flops_per_step(r: int, s: int, m: int) -> int:
    """Multiply-adds x 2 of one step: [SM SC] z (2 r^2), K_eff^-1 p (r m), SB w (r s) twice,
    state update (~10 r); the s-dimensional Newton solve is negligible for s << r."""
    return 2 * (2 * r * r + r * m + 2 * r * s) + 10 * r


def gemm_rate(r: int) -> float:
    """Flop rate [flop/s] of BLAS on the same matrix shape, as the machine's reference."""
    H, Z = np.random.default_rng(0).standard_normal((r, 2 * r)), np.ones((2 * r, 20000))
    start = time.perf_counter()
    for _ in range(5):
        H @ Z
    return 5 * 2 * r * 2 * r * 20000 / (time.perf_counter() - start)


def integration_rate(model: StructuralModel, excitation: Excitation,
                     steps: int) -> tuple[float, float]:
    """Steps per second of the bare integration (wall clock, CPU time), recording OUTPUTS
    displacements. One realisation runs on one core; CPU time is immune to other load."""
    integrator = NewmarkIntegrator(model, 1 / FS_INT, excitation.loads(model.dof_names))
    u = upsample(excitation.u, int(FS_INT / FS))
    record = (np.arange(min(OUTPUTS, model.n_dofs)), np.zeros(0, int), np.zeros(0, int))
    for _ in integrator.run(u, 1000, record):  # compile / load the cached kernels
        pass
    start, cpu = time.perf_counter(), time.process_time()
    for _ in integrator.run(u, steps, record, chunk=SAMPLES * int(FS_INT / FS)):
        pass
    return steps / (time.perf_counter() - start), steps / (time.process_time() - cpu)


def batch_speedup(model: StructuralModel, realisations: int = 2) -> float:
    """Time of ``realisations`` load cases one by one over the time integrated together
    (one period each; they run on parallel threads)."""
    signals = periodic_noise(SAMPLES, FS, (5.0, 50.0), 100.0, realisations=realisations)
    batch = Excitation.at_dof(signals, FS, model.dof_names[0])
    integrator = NewmarkIntegrator(model, 1 / FS_INT, batch.loads(model.dof_names))
    u = upsample(batch.u, int(FS_INT / FS))
    record = (np.arange(min(OUTPUTS, model.n_dofs)), np.zeros(0, int), np.zeros(0, int))
    steps = SAMPLES * int(FS_INT / FS)
    for _ in integrator.run(u, 1000, record):  # compile / load the parallel kernel
        pass
    start = time.perf_counter()
    for k in range(realisations):
        for _ in integrator.run(u[k:k + 1], steps, record, chunk=steps):
            pass
    one_by_one = time.perf_counter() - start
    start = time.perf_counter()
    for _ in integrator.run(u, steps, record, chunk=steps):
        pass
    return one_by_one / (time.perf_counter() - start)


def main() -> None:
    steps = PERIODS * SAMPLES * int(FS_INT / FS)
    try:
        from fnsi.smallsat import simulate_preset, smallsat_model
        model = smallsat_model()
        source = "fnsi.smallsat simulate_preset('single')"
    except (ImportError, ValueError, OSError) as error:  # SmallSat model not available
        simulate_preset, model = None, random_model()
        source = (f"random model, {model.n_dofs} DOFs, {len(model.elements)} clearance stops "
                  f"(no SmallSat: {str(error)[:80]})")
    excitation = preset_excitation(model.dof_names)
    rate, cpu_rate = integration_rate(model, excitation, steps)

    start = time.perf_counter()
    if simulate_preset is not None:
        simulate_preset("single")
    else:
        _, truth = acquire(model, excitation, fs=FS, fs_int=FS_INT, periods=PERIODS,
                           outputs=model.dof_names[:OUTPUTS])
        print(f"exceedances: {truth.exceedances}")
    preset = time.perf_counter() - start

    r, s = model.n_dofs, len(model.elements)
    flops = flops_per_step(r, s, 1)
    reference = gemm_rate(r)
    print(f"model: {source}")
    print(f"integration: {steps:,} steps at {rate:,.0f} steps/s wall "
          f"({1e6 / rate:.2f} us/step, {steps / rate:.2f} s); CPU time {1e6 / cpu_rate:.2f} "
          "us/step")
    print(f"flop count: {flops:,} flop/step -> {flops * cpu_rate / 1e9:.2f} GFlop/s per core "
          f"(CPU time); BLAS gemm on (r, 2r) reaches {reference / 1e9:.2f} GFlop/s")
    budget = 15.0 - (preset - steps / rate)  # the rest of the preset does not scale with r^2
    print(f"predicted step time at the BLAS rate: {1e6 * flops / reference:.2f} us; the step "
          f"cost is O(r^2), so the 15 s target allows r <= "
          f"{r * np.sqrt(max(budget, 0.0) * rate / steps):.0f} DOFs at this machine's load")
    print(f"single preset (integration + decimation + noise): {preset:.2f} s")
    print(f"2 realisations together: {batch_speedup(model):.2f}x faster than one by one")
    print(json.dumps({"single_preset_s": round(preset, 3), "steps_per_s": round(rate),
                      "n_dofs": r}))


if __name__ == "__main__":
    main()
