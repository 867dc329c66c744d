"""Phase 2: identify every case with the library as a user would, blind to the truth.

Linear part (issue 20), :func:`answer`:

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

import math
import time
import traceback
import warnings
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from benchmarks.generalisation.blind import (
    answer_path,
    blindfold,
    cases_dir,
    read_index,
    write_json,
)
from benchmarks.generalisation.provenance import file_digest, machine
from fnsi.errors import json_float
from fnsi.identification import IdentificationSettings, identify
from fnsi.measurement import Measurement
from fnsi.simulation_order import pooled_error
from fnsi.study import Study
from fnsi.validation import compare

#: Diagnosis rounds of the study loop (issue 21: both effects of a pair in two rounds).
ROUNDS = 2


def _measurement(data, suffix: str = "") -> Measurement:
    """The record ``u<suffix>``, ``y<suffix>`` of a case file as a measurement."""
    return Measurement.from_arrays(
        data["u" + suffix], data["y" + suffix], float(data["fs"]),
        periods=int(data["periods"]), quantity=str(data["quantity"]),
        input_names=data["input_names"], output_names=data["output_names"])


def answer(path: Path) -> dict:
    """The library's answer for one case file (never reads anything else)."""
    with np.load(path, allow_pickle=False) as data:
        measurement = _measurement(data)
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


def answer_study(path: Path) -> dict:
    """The study loop's answer for one hidden-effect case file (module docstring)."""
    with np.load(path, allow_pickle=False) as data:
        estimation, validation = _measurement(data), _measurement(data, "_validation")
        band = tuple(float(b) for b in data["band"])
    start = time.perf_counter()
    rounds: list[dict] = []
    try:
        study = Study.create(estimation, validation, IdentificationSettings(band=band))
        create_s = time.perf_counter() - start
        for _ in range(ROUNDS):
            start = time.perf_counter()
            diagnosis = study.diagnose()
            rounds.append({"diagnosis_s": time.perf_counter() - start,
                           "found": diagnosis.found, "summary": diagnosis.summary,
                           "nrmse_before_pct": json_float(diagnosis.nrmse_before_percent),
                           "candidates": [c.to_json() for c in diagnosis.candidates]})
            if not diagnosis.found:
                break
            top = diagnosis.candidates[0]
            if top.elements:   # a pair's claim adds both
                study.add_revision(add=top.elements)
            else:
                study.add_revision(order=top.order, note="one more mode")
    except Exception as error:  # a refusal or a crash is the library's answer too
        return {"status": "error", "error": f"{type(error).__name__}: {error}",
                "where": traceback.format_exc(limit=-2), "rounds": rounds}
    return {"status": "ok", "create_s": create_s, "rounds": rounds,
            "noise_floor_pct": json_float(study.noise_floor_percent),
            "estimation_pct": json_float(_estimation_percent(study)),
            "warnings": study.warnings,
            "revisions": [{"note": r.note, "order": r.identified_order,
                           "elements": [e.to_json() for e in r.elements],
                           "nrmse_pct": json_float(r.nrmse_percent), "failure": r.failure}
                          for r in study.revisions]}


def _estimation_percent(study: Study) -> float:
    """Revision 0's simulation error of the estimation record, all channels and
    realisations pooled by their power on the lines the study compares [%]: beside the
    validation error, it tells a linear model that fits the record it was identified
    from better than the true linear structure does (the records differ, or it absorbed
    the record's distortion) from one that fits neither."""
    settings = study.settings
    try:
        comparison = compare(study.revisions[0].model, study.estimation,
                             discard_periods=settings.discard_periods,
                             band_high=settings.band[1], offsets_removed=settings.remove_offsets)
    except ValueError:   # an unstable revision 0 has no simulation
        return math.inf
    return pooled_error(comparison.errors)[0]


def _answer_case(task: tuple[Path, str, bool]) -> tuple[str, dict]:
    """Answer one case and write it (a process-pool task, blindfolded in its process)."""
    root, case, hidden = task
    with blindfold(root):
        path = cases_dir(root) / f"{case}.npz"
        result = {"case": case, **(answer_study(path) if hidden else answer(path)),
                  "provenance": {"digest": file_digest(path), "machine": machine()}}
        write_json(answer_path(root, case), result)
    return case, result


def run(root: Path, progress: Callable[[str, dict], None] | None = None,
        jobs: int = 1) -> None:
    """Answer every case of ``root`` without an answer yet (phase 2; resumable).

    Parameters
    ----------
    root : path
        Benchmark directory written by :func:`.cases.generate` or
        :func:`.hidden.generate_hidden` (the index says which part).
    progress : callable(case, answer), optional
        Called after each answer is written.
    jobs : int
        Processes answering cases in parallel (each under its own blindfold).
    """
    index = read_index(root)
    hidden = index.get("part") == "hidden"
    tasks = [(Path(root), case, hidden) for case in index["cases"]
             if not answer_path(root, case).is_file()]
    with blindfold(root), ProcessPoolExecutor(max_workers=jobs) as pool:
        for case, result in pool.map(_answer_case, tasks):
            if progress is not None:
                progress(case, result)
