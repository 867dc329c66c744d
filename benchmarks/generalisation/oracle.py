"""Phase 4 of the hidden-effect half (issue 21): what the loop could reach with the truth.

A failed case is either *diagnosis-limited* (the library models the hidden effect well
once told what and where it is, but its diagnosis did not find it) or
*identification-limited* (even the true elements, added to the library's linear
revision, leave the validation error far above the noise floor: no diagnosis can do
better than the identification lets it). This phase tells them apart, and so says where
the next work pays.

Run after the answers are recorded (:func:`.blind.require_answers`): per case with an
effect, the study is created as the loop created it and the true elements are added in
one revision (:meth:`fnsi.study.Study.add_revision`, refined when the study would refine
it), its validation NRMSE recorded in ``oracle/<case>.json``. The truth's parameters are
used as they are, except where a record does not fix them:

- a clearance's gaps are relative to the structure's rest position; the library sees the
  relative displacement of a velocity or acceleration record about its mean, which a
  contact moves. One offset c maps the truth into that coordinate (contact above g+ - c
  and below -(g- + c)): the gaps as drawn (c = 0) and those with the offset that fits
  the estimation residual best with the poles held (:mod:`fnsi.screening`, as the
  diagnosis searches gaps) are both added, and the better validated is kept. The oracle
  thus reads the validation record to choose between two readings of the truth, which
  the loop cannot: it bounds what the loop could reach.
- Coulomb friction and polynomial laws are given exactly (their coefficient is what FNSI
  identifies).
"""

from __future__ import annotations

import json
import math
import time
import traceback
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from scipy.optimize import minimize_scalar

from benchmarks.generalisation.blind import (
    answer_path,
    cases_dir,
    require_answers,
    truth_path,
    write_json,
)
from benchmarks.generalisation.hidden_scoring import FLOOR_FACTOR
from benchmarks.generalisation.runner import _measurement
from benchmarks.generalisation.structures import GROUND
from fnsi.diagnosis import _fit_with_linear, _screening_model
from fnsi.errors import json_float
from fnsi.identification import IdentificationSettings
from fnsi.nonlinear import NonlinearElement
from fnsi.screening import ScreeningProblem
from fnsi.study import Study

OFFSET_GRID = 41
"""Offsets tried over the measured relative displacement range before the bounded search."""


def oracle_path(root: Path, case: str) -> Path:
    """Where the oracle result of a case is written."""
    return Path(root) / "oracle" / f"{case}.json"


def _name(dof: int) -> str | None:
    return None if dof == GROUND else f"x{dof}"


def library_element(element: dict, offset: float = 0.0) -> NonlinearElement:
    """The library's element for a truth element (:class:`.structures.Element` as JSON),
    a clearance's gaps moved by ``offset`` (module docstring)."""
    dof, ref = _name(element["dof"]), _name(element["ref"])
    kind = element["kind"]
    if kind in ("cubic", "quadratic"):
        return NonlinearElement("polynomial", dof, ref, exponent=3.0 if kind == "cubic" else 2.0,
                                signed=kind == "cubic")
    if kind == "coulomb":
        return NonlinearElement("coulomb_friction", dof, ref, width=element["width"])
    if kind == "quadratic_damping":
        return NonlinearElement("quadratic_damping", dof, ref)
    gn, gp = element["gaps"]
    gn, gp = gn + offset, gp - offset
    if math.isinf(gn):
        return NonlinearElement("clearance", dof, ref, gap_positive=gp, side="positive")
    if math.isinf(gp):
        return NonlinearElement("clearance", dof, ref, gap_negative=gn, side="negative")
    return NonlinearElement("clearance", dof, ref, gap_negative=gn, gap_positive=gp)


def _offset(problem: ScreeningProblem, element: dict) -> float:
    """The offset c of a clearance that fits the estimation residual best with the poles
    held, over the offsets that keep each gap positive and inside the motion (a contact
    never reached is no element: FNSI refuses its zero basis)."""
    x, _ = problem.motion.relative(_name(element["dof"]), _name(element["ref"]))
    gn, gp = element["gaps"]
    low, high = x.min(), x.max()
    if math.isfinite(gp):   # 0 < g+ - c < max x
        low, high = max(low, gp - x.max()), min(high, gp)
    if math.isfinite(gn):   # 0 < g- + c < -min x
        low, high = max(low, -gn), min(high, -x.min() - gn)
    if not low < high:   # no offset keeps both contacts inside the motion
        return 0.0
    # strictly inside: a zero gap is refused, and a contact beyond the motion fits nothing
    span = high - low
    low, high = low + 1e-3 * span, high - 1e-3 * span

    def cost(c: float) -> float:
        return _fit_with_linear(problem, library_element(element, c))

    grid = np.linspace(low, high, OFFSET_GRID)
    values = [cost(c) for c in grid]
    best = int(np.argmin(values))
    result = minimize_scalar(cost, bounds=(grid[max(best - 1, 0)],
                                           grid[min(best + 1, grid.size - 1)]),
                             method="bounded", options={"xatol": 1e-4 * span})
    return float(result.x) if result.fun < values[best] else float(grid[best])


def oracle_case(path: Path, truth: dict) -> dict:
    """The true elements added to the library's linear revision of one case file."""
    with np.load(path, allow_pickle=False) as data:
        estimation, validation = _measurement(data), _measurement(data, "_validation")
        band = tuple(float(b) for b in data["band"])
    start = time.perf_counter()
    study = Study.create(estimation, validation, IdentificationSettings(band=band))
    base = study.revisions[0]
    clearances = [e["kind"] == "clearance" for e in truth["elements"]]
    offsets = [[0.0] * len(clearances)]
    if any(clearances):
        problem = ScreeningProblem(study.identified_estimation, _screening_model(study, base),
                                   study.settings.band, study.settings.discard_periods)
        offsets.append([_offset(problem, e) if c else 0.0
                        for e, c in zip(truth["elements"], clearances, strict=True)])
    tried = []
    for choice in offsets:
        elements = [library_element(e, c) for e, c in zip(truth["elements"], choice,
                                                          strict=True)]
        try:
            tried.append((study.add_revision(add=elements, note="true elements"), elements))
        except ValueError as error:   # e.g. a contact the estimation record never reaches
            failure = str(error)
    if not tried:
        raise ValueError(failure)
    revision, elements = min(tried, key=lambda t: t[0].nrmse_percent)
    return {"status": "ok", "seconds": time.perf_counter() - start,
            "noise_floor_pct": json_float(study.noise_floor_percent),
            "linear_pct": json_float(base.nrmse_percent),
            "oracle_pct": json_float(revision.nrmse_percent), "order": revision.identified_order,
            "elements": [e.to_json() for e in elements], "failure": revision.failure,
            "refined": revision.refinement is not None}


def _oracle_task(task: tuple[Path, str, dict]) -> tuple[str, dict]:
    root, case, truth = task
    try:
        result = oracle_case(cases_dir(root) / f"{case}.npz", truth)
    except Exception as error:  # the library's refusal is a result too
        result = {"status": "error", "error": f"{type(error).__name__}: {error}",
                  "where": traceback.format_exc(limit=-2)}
    write_json(oracle_path(root, case), {"case": case, **result})
    return case, result


def run_oracle(root: Path, progress: Callable[[str, dict], None] | None = None,
               jobs: int = 1) -> None:
    """Phase 4 for every case with an effect and no oracle result yet (resumable).

    Raises
    ------
    ValueError
        When some case has no answer yet (the truth stays sealed until then).
    """
    cases = require_answers(root)
    truths = json.loads(truth_path(root).read_text())["cases"]
    tasks = [(Path(root), case, truths[case]) for case in cases
             if truths[case]["elements"] and not oracle_path(root, case).is_file()]
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        for case, result in pool.map(_oracle_task, tasks):
            if progress is not None:
                progress(case, result)


def _reached(pct: float | None, floor: float | None) -> bool:
    return pct is not None and floor is not None and pct <= FLOOR_FACTOR * floor


def oracle_report(root: Path) -> tuple[str, dict]:
    """Markdown table of the oracle against the loop, and its summary.

    Per kind class: cases, the loop's floor reached, the oracle's floor reached, and the
    loop's failures split into diagnosis-limited (the oracle reaches the floor) and
    identification-limited (it does not).
    """
    truths = json.loads(truth_path(root).read_text())["cases"]
    rows = []
    for case, truth in sorted(truths.items()):
        if not truth["elements"] or not oracle_path(root, case).is_file():
            continue
        oracle = json.loads(oracle_path(root, case).read_text())
        answer = json.loads(answer_path(root, case).read_text())
        floor = oracle.get("noise_floor_pct")
        loop = (answer["revisions"][-1]["nrmse_pct"] if answer["status"] == "ok" else None)
        kind = " + ".join(sorted(e["kind_class"] for e in truth["elements"]))
        rows.append((case, kind, truth["plan"]["quantity"], floor, oracle.get("linear_pct"),
                     loop, oracle.get("oracle_pct"), _reached(loop, floor),
                     _reached(oracle.get("oracle_pct"), floor)))
    lines = ["| kind | cases | loop reaches 2x floor | oracle reaches 2x floor | "
             "diagnosis-limited | identification-limited |", "|---|---|---|---|---|---|"]
    kinds = sorted({r[1] for r in rows})
    for kind in [*kinds, "all"]:
        group = [r for r in rows if kind in ("all", r[1])]
        loop_ok, oracle_ok = sum(r[7] for r in group), sum(r[8] for r in group)
        diagnosis = sum(not r[7] and r[8] for r in group)
        identification = sum(not r[7] and not r[8] for r in group)
        lines.append(f"| {kind} | {len(group)} | {loop_ok} | {oracle_ok} | {diagnosis} | "
                     f"{identification} |")
    lines += ["", "| case | kind | quantity | floor % | linear % | loop % | oracle % |",
              "|---|---|---|---|---|---|---|"]
    for case, kind, quantity, floor, linear, loop, oracle, *_ in rows:
        lines.append(f"| {case} | {kind} | {quantity} | {_pct(floor)} | {_pct(linear)} | "
                     f"{_pct(loop)} | {_pct(oracle)} |")
    summary = {"cases": len(rows),
               "loop_floor_reached": sum(r[7] for r in rows),
               "oracle_floor_reached": sum(r[8] for r in rows),
               "diagnosis_limited": sum(not r[7] and r[8] for r in rows),
               "identification_limited": sum(not r[7] and not r[8] for r in rows)}
    return "\n".join(lines) + "\n", summary


def _pct(value: float | None) -> str:
    return "-" if value is None else f"{value:.3g}"
