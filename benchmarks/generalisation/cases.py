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
from dataclasses import dataclass

import numpy as np

from benchmarks.generalisation import synthesis
from benchmarks.generalisation.blind import fresh_cases_dir, truth_path, write_json
from benchmarks.generalisation.provenance import file_digest
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


@dataclass(frozen=True)
class Setup:
    """A drawn structure and test: everything but the response.

    Attributes
    ----------
    structure : Structure
    band : (float, float)
        Excitation band [Hz], edges half a line off the excited lines.
    fs : float
        Sampling rate [Hz].
    samples : int
        Samples per period.
    lines : ndarray of int
        Excited DFT lines.
    inputs, sensors : ndarray of int
        DOFs of the forces and of the measured outputs.
    quantity : str
        Output quantity.
    realisations : int
    noise : float
        Noise RMS as a fraction of each channel's RMS (0 when noise free).
    spectrum : ndarray, shape (realisations, samples // 2 + 1, inputs), complex
        :func:`.synthesis.multisine` half spectra of the forces.
    """

    structure: Structure
    band: tuple[float, float]
    fs: float
    samples: int
    lines: np.ndarray
    inputs: np.ndarray
    sensors: np.ndarray
    quantity: str
    realisations: int
    noise: float
    spectrum: np.ndarray

    def plan(self, kind: str) -> dict:
        """The drawn settings in words and numbers (tables group cases by them)."""
        s = self.structure
        return {"kind": kind, "topology": s.topology, "dofs": s.n_dofs,
                "close_modes": s.close_modes, "damping": s.damping,
                "inputs": int(self.inputs.size), "sensors": int(self.sensors.size),
                "quantity": self.quantity, "noise_pct": 100 * self.noise,
                "fs_ratio": self.fs / self.band[1], "realisations": self.realisations,
                "samples_per_period": self.samples, "band_hz": list(self.band)}

    def data(self, u: np.ndarray, y: np.ndarray) -> dict:
        """The canonical NPZ dataset of records ``u``, ``y`` (all periods) plus the band."""
        return {"u": u, "y": y, "fs": np.float64(self.fs), "periods": np.int64(PERIODS),
                "quantity": np.str_(self.quantity), "band": np.array(self.band),
                "input_names": np.array([f"F_x{d}" for d in self.inputs]),
                "output_names": np.array([f"x{d}" for d in self.sensors])}


def draw_setup(rng: np.random.Generator, *, noise_free: bool = False,
               lines_range: tuple[float, float] = (150, 400),
               max_samples: int = MAX_SAMPLES) -> Setup:
    """Draw a structure and its test over the ranges of the module docstring.

    Parameters
    ----------
    rng : numpy.random.Generator
    noise_free : bool
        Noise scaled to zero (every draw kept).
    lines_range : (float, float)
        Range of the number of excited lines in the band (uniform).
    max_samples : int
        Largest number of samples per period.
    """
    topology = TOPOLOGIES[int(rng.integers(len(TOPOLOGIES)))]
    n = int(rng.integers(2, 13))
    close = bool(n >= 3 and rng.random() < 0.25)
    structure = draw_structure(rng, n, topology, close_modes=close,
                               proportional=bool(rng.random() < 0.5),
                               first_frequency=log_uniform(rng, 2.0, 50.0))
    n = structure.n_dofs
    f, _ = frequencies_damping(modes(structure.M, structure.C, structure.K)[0])
    low, high = _band(rng, f)
    fs = log_uniform(rng, 4.0, 40.0) * high
    lines_wanted = rng.uniform(*lines_range)
    samples = int(np.clip(2 * round(lines_wanted * fs / (high - low) / 2), 256, max_samples))
    df = fs / samples
    # edges half a line off the excited ones: no rounding decides which lines are in
    band = (float((np.ceil(low / df) - 0.5) * df), float((np.ceil(high / df) - 0.5) * df))
    lines = synthesis.excited_lines(samples, fs, band)
    inputs = rng.choice(n, size=int(rng.integers(1, 3)), replace=False)
    sensors = np.sort(rng.choice(n, size=int(rng.integers(1, min(n, MAX_SENSORS) + 1)),
                                 replace=False))
    quantity = synthesis.QUANTITIES[int(rng.integers(3))]
    realisations = int(rng.integers(1, 3))
    noise = log_uniform(rng, 0.001, 0.05) * (0.0 if noise_free else 1.0)  # same draws
    spectrum = synthesis.multisine(rng, realisations, samples, lines, inputs.size)
    return Setup(structure, band, float(fs), samples, lines, inputs, sensors, quantity,
                 realisations, float(noise), spectrum)


def add_noise(rng: np.random.Generator, x: np.ndarray, noise: float) -> np.ndarray:
    """``x`` (realisations, samples, channels) plus white noise of ``noise`` times each
    channel's RMS."""
    return x + noise * np.sqrt(np.mean(x**2, axis=1, keepdims=True)) * rng.standard_normal(
        x.shape)


def draw_case(seed: np.random.SeedSequence, *, noise_free: bool = False,
              ) -> tuple[dict, dict, dict]:
    """One random linear case.

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
    setup = draw_setup(rng, noise_free=noise_free)
    structure, band, lines = setup.structure, setup.band, setup.lines
    u, y = synthesis.steady_state(structure.M, structure.C, structure.K, setup.spectrum,
                                  setup.samples, lines, setup.fs, setup.sensors,
                                  setup.inputs, setup.quantity)
    u, y = (add_noise(rng, np.tile(x, (1, PERIODS, 1)), setup.noise) for x in (u, y))
    df = setup.fs / setup.samples
    poles, _ = modes(structure.M, structure.C, structure.K)
    f, zeta = frequencies_damping(poles)
    _, terms = synthesis.modal_receptance(structure.M, structure.C, structure.K, lines * df)
    shares = synthesis.power_shares(terms, setup.spectrum[:, lines], synthesis.derivative(
        lines * df, setup.quantity), setup.sensors, setup.inputs)
    in_band = (f >= band[0]) & (f < band[1])
    plan = setup.plan("linear")
    truth = {"plan": plan, "modes": [
        {"frequency_hz": float(fr), "damping_ratio": float(z), "power_share": float(s),
         "in_band": bool(b), "required": bool(b and s >= REQUIRED_SHARE)}
        for fr, z, s, b in zip(f, zeta, shares, in_band, strict=True)],
        "structure": structure_json(structure, setup.inputs, setup.sensors)}
    return setup.data(u, y), plan, truth


def structure_json(structure: Structure, inputs: np.ndarray, sensors: np.ndarray) -> dict:
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
    directory = fresh_cases_dir(root)
    ids, truths = [], {}
    for k, child in enumerate(np.random.SeedSequence(seed).spawn(count)):
        case = f"case{k:04d}"
        data, _, truth = draw_case(child, noise_free=noise_free)
        np.savez(directory / f"{case}.npz", **data)
        ids.append(case)
        truths[case] = truth
    write_json(truth_path(root), {"seed": seed, "cases": truths})
    write_json(directory / "index.json", {
        "seed": seed, "count": count, "cases": ids,
        "digests": {case: file_digest(directory / f"{case}.npz") for case in ids}})
    return ids
