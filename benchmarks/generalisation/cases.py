"""Phase 1: draw the benchmark's test cases at random and write them, truth sealed apart.

Every quantity of a case is drawn from the seed of that case (``SeedSequence(seed)``'s
k-th child), so case k is the same whatever the count: a run of 30 cases is the first
30 cases of a run of 100. Ranges (issue 20):

========================  ======================================================
topology                  chain, branched tree, lumped grid (uniform)
DOFs                      2-12 (uniform; a symmetric grid takes 4 or 9)
close modes               25 %: symmetric structure mistuned by 0.5-3 %
damping                   every mode 0.5-10 %; proportional or not (1:1)
lowest frequency          2-50 Hz (log-uniform)
inputs                    1 or 2 forces at random DOFs
sensors                   1 to min(DOFs, 8) at random DOFs
output                    displacement, velocity or acceleration
noise                     0.1-5 % of each channel's RMS (log-uniform), inputs too
fs                        4-40 times the band's upper edge (log-uniform)
band                      a random run of consecutive modes, edges between modes
record                    3 periods (the first is the user's transient period),
                          1 or 2 realisations, 150-400 lines in the band
========================  ======================================================

A mode is *required* when its natural frequency is in the band and it carries at least
1 % of the response power in the band at the sensors (:func:`.synthesis.power_shares`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from benchmarks.generalisation import synthesis
from benchmarks.generalisation.blind import cases_dir, truth_path, write_json
from benchmarks.generalisation.structures import (
    TOPOLOGIES,
    Structure,
    draw_structure,
    frequencies_damping,
    log_uniform,
    modes,
)

#: Smallest share of the band's response power that a mode must carry to be required.
REQUIRED_SHARE = 0.01
PERIODS = 3
MAX_SENSORS = 8
MAX_SAMPLES = 8192


def _band(rng: np.random.Generator, f: np.ndarray) -> tuple[float, float]:
    """Band over a random run of consecutive modes, its edges a random fraction of the way
    to the neighbouring modes, and never splitting two modes within 10 % of each other."""
    n = f.size
    first = 0 if rng.random() < 0.7 else int(rng.integers(n))
    last = int(rng.integers(first, n))
    while first > 0 and f[first] / f[first - 1] < 1.1:
        first -= 1
    while last < n - 1 and f[last + 1] / f[last] < 1.1:
        last += 1
    low = (f[first] * rng.uniform(0.2, 0.7) if first == 0
           else f[first] - rng.uniform(0.35, 0.65) * (f[first] - f[first - 1]))
    high = (f[last] * rng.uniform(1.1, 1.5) if last == n - 1
            else f[last] + rng.uniform(0.35, 0.65) * (f[last + 1] - f[last]))
    return float(low), float(high)


def draw_case(seed: np.random.SeedSequence, *, noise_free: bool = False,
              ) -> tuple[dict, dict, dict]:
    """One random case.

    Parameters
    ----------
    seed : numpy.random.SeedSequence
    noise_free : bool
        The same case without measurement noise (every draw is kept, the noise is scaled
        to zero): every case must then have an order that finds its modes, which checks
        the generator's truth against the data.

    Returns
    -------
    data : dict
        Arrays of the canonical NPZ dataset (``u``, ``y`` as (realisations, samples,
        channels), ``fs``, ``periods``, ``quantity``, channel names) plus ``band`` [Hz],
        the excitation band the user knows.
    plan : dict
        The drawn settings (topology, DOFs, damping kind, noise, fs ratio, ...).
    truth : dict
        Modes (frequency [Hz], damping ratio, power share, in band, required), the
        structure's matrices and the plan.
    """
    rng = np.random.default_rng(seed)
    topology = TOPOLOGIES[int(rng.integers(len(TOPOLOGIES)))]
    n = int(rng.integers(2, 13))
    close = bool(n >= 3 and rng.random() < 0.25)
    structure = draw_structure(rng, n, topology, close_modes=close,
                               proportional=bool(rng.random() < 0.5),
                               first_frequency=log_uniform(rng, 2.0, 50.0))
    n = structure.n_dofs
    poles, _ = modes(structure.M, structure.C, structure.K)
    f, zeta = frequencies_damping(poles)
    low, high = _band(rng, f)
    ratio = log_uniform(rng, 4.0, 40.0)
    fs = ratio * high
    lines_wanted = rng.uniform(150, 400)
    samples = int(np.clip(2 * round(lines_wanted * fs / (high - low) / 2), 256, MAX_SAMPLES))
    df = fs / samples
    # edges half a line off the excited ones: no rounding decides which lines are in
    band = ((np.ceil(low / df) - 0.5) * df, (np.ceil(high / df) - 0.5) * df)
    lines = synthesis.excited_lines(samples, fs, band)
    inputs = rng.choice(n, size=int(rng.integers(1, 3)), replace=False)
    sensors = np.sort(rng.choice(n, size=int(rng.integers(1, min(n, MAX_SENSORS) + 1)),
                                 replace=False))
    quantity = synthesis.QUANTITIES[int(rng.integers(3))]
    realisations = int(rng.integers(1, 3))
    noise = log_uniform(rng, 0.001, 0.05) * (0.0 if noise_free else 1.0)  # same draws
    spectrum = synthesis.multisine(rng, realisations, samples, lines, inputs.size)
    u, y = synthesis.steady_state(structure.M, structure.C, structure.K, spectrum, samples,
                                  lines, fs, sensors, inputs, quantity)
    u, y = (np.tile(x, (1, PERIODS, 1)) for x in (u, y))
    u, y = (x + noise * np.sqrt(np.mean(x**2, axis=1, keepdims=True))
            * rng.standard_normal(x.shape) for x in (u, y))
    _, terms = synthesis.modal_receptance(structure.M, structure.C, structure.K, lines * df)
    shares = synthesis.power_shares(terms, spectrum[:, lines], synthesis.derivative(
        lines * df, quantity), sensors, inputs)
    in_band = (f >= band[0]) & (f < band[1])
    names = [f"x{d}" for d in sensors]
    data = {"u": u, "y": y, "fs": np.float64(fs), "periods": np.int64(PERIODS),
            "quantity": np.str_(quantity), "band": np.array(band),
            "input_names": np.array([f"F_x{d}" for d in inputs]),
            "output_names": np.array(names)}
    plan = {"kind": "linear", "topology": topology, "dofs": n, "close_modes": close,
            "damping": structure.damping, "inputs": int(inputs.size),
            "sensors": int(sensors.size), "quantity": quantity, "noise_pct": 100 * noise,
            "fs_ratio": fs / band[1], "realisations": realisations,
            "samples_per_period": samples, "band_hz": list(band)}
    truth = {"plan": plan, "modes": [
        {"frequency_hz": float(fr), "damping_ratio": float(z), "power_share": float(s),
         "in_band": bool(b), "required": bool(b and s >= REQUIRED_SHARE)}
        for fr, z, s, b in zip(f, zeta, shares, in_band, strict=True)],
        "structure": _structure_json(structure, inputs, sensors)}
    return data, plan, truth


def _structure_json(structure: Structure, inputs: np.ndarray, sensors: np.ndarray) -> dict:
    return {"topology": structure.topology, "springs": [list(s) for s in structure.springs],
            "M": structure.M.tolist(), "C": structure.C.tolist(), "K": structure.K.tolist(),
            "elements": [dataclasses.asdict(e) for e in structure.elements],
            "input_dofs": inputs.tolist(), "sensor_dofs": sensors.tolist()}


def generate(root, seed: int, count: int, *, noise_free: bool = False) -> list[str]:
    """Write ``count`` cases under ``root`` (phase 1) and seal their truth.

    Parameters
    ----------
    root : path
        Benchmark directory (see :mod:`.blind`); must not hold cases yet.
    seed : int
        Master seed; the same seed and count give the same files.
    count : int
        Number of cases.
    noise_free : bool
        Cases without measurement noise (:func:`draw_case`).

    Returns
    -------
    list of str
        Case ids.
    """
    directory = cases_dir(root)
    if (directory / "index.json").exists():
        raise ValueError(f"{directory} already holds cases; use a fresh directory")
    directory.mkdir(parents=True, exist_ok=True)
    ids, truths = [], {}
    for k, child in enumerate(np.random.SeedSequence(seed).spawn(count)):
        case = f"case{k:04d}"
        data, _, truth = draw_case(child, noise_free=noise_free)
        np.savez(directory / f"{case}.npz", **data)
        ids.append(case)
        truths[case] = truth
    write_json(truth_path(root), {"seed": seed, "cases": truths})
    write_json(directory / "index.json", {"seed": seed, "count": count, "cases": ids})
    return ids
