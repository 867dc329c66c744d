"""Phase 2: identify every case with the library as a user would, blind to the truth.

Each case's NPZ gives what a user has: forces, responses, fs, periods, output quantity,
channel names and the band of the excitation they designed. The library runs with its
defaults (:class:`fnsi.identification.IdentificationSettings` with only the band given:
order and block rows ``"auto"``), inside :func:`.blind.blindfold`. The answer records the
modes reported, the order, the largest discrete-time pole modulus of the model (above 1:
the model cannot be simulated), the warnings the library raised, the wall time of
:func:`fnsi.identification.identify`, and the modes of every order of the stabilisation
diagram (what an explicit order would have returned: the scorer tells a wrong order choice
from a case that no order fits); a refusal or crash is recorded as the answer.
"""

from __future__ import annotations

import time
import traceback
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np

from benchmarks.generalisation.blind import (
    answer_path,
    blindfold,
    cases_dir,
    read_index,
    write_json,
)
from fnsi.identification import IdentificationSettings, identify
from fnsi.measurement import Measurement


def answer(path: Path) -> dict:
    """The library's answer for one case file (never reads anything else)."""
    with np.load(path, allow_pickle=False) as data:
        measurement = Measurement.from_arrays(
            data["u"], data["y"], float(data["fs"]), periods=int(data["periods"]),
            quantity=str(data["quantity"]), input_names=data["input_names"],
            output_names=data["output_names"])
        band = tuple(float(b) for b in data["band"])
    settings = IdentificationSettings(band=band)
    start = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            result = identify(measurement, settings)
        except Exception as error:  # a refusal or a crash is the library's answer too
            return {"status": "error", "error": f"{type(error).__name__}: {error}",
                    "where": traceback.format_exc(limit=-2),
                    "identify_s": time.perf_counter() - start,
                    "warnings": [str(w.message) for w in caught]}
    elapsed = time.perf_counter() - start
    modal = result.modal
    diagram = result.stabilisation
    return {"status": "ok", "order": result.order,
            "block_rows": None if result.settings is None else result.settings.block_rows,
            "modes": _modes(modal),
            "max_pole_modulus": float(np.max(np.abs(np.linalg.eigvals(result.model.A)),
                                             initial=0.0)),
            "warnings": [str(w.message) for w in caught], "identify_s": elapsed,
            "diagram": [] if diagram is None else [
                {"order": order, "modes": _modes(diagram.at(order).modes)}
                for order in diagram.orders]}


def _modes(table) -> list[dict]:
    """Frequencies [Hz], damping ratios and confirmed flags of a modal table."""
    confirmed = ([None] * table.n_modes if table.confirmed is None
                 else [bool(c) for c in table.confirmed])
    return [{"frequency_hz": float(f), "damping_ratio": float(z), "confirmed": c}
            for f, z, c in zip(table.frequencies, table.damping_ratios, confirmed,
                               strict=True)]


def run(root: Path, progress: Callable[[str, dict], None] | None = None) -> None:
    """Answer every case of ``root`` without an answer yet (phase 2; resumable).

    Parameters
    ----------
    root : path
        Benchmark directory written by :func:`.cases.generate`.
    progress : callable(case, answer), optional
        Called after each answer is written.
    """
    cases = read_index(root)["cases"]
    with blindfold(root):
        for case in cases:
            target = answer_path(root, case)
            if target.is_file():
                continue
            result = {"case": case, **answer(cases_dir(root) / f"{case}.npz")}
            write_json(target, result)
            if progress is not None:
                progress(case, result)
