"""Phase 3 of the hidden-effect half (issue 21): the study loop's answers against the
sealed truth, and the results table.

Opened only after :func:`.blind.require_answers` has found every answer on disk.

Kinds are compared in classes (:func:`.hidden.kind_class`): hardening and softening cubic
springs are one kind (the sign is a parameter), symmetric and asymmetric clearances one
kind (two-sided contact), a one-sided stop another (its side must match too), then
quadratic stiffness, Coulomb friction and quadratic damping. A location is the unordered
pair of DOFs, or a DOF and the ground. A claimed clearance is a stop when only one of
its gaps lies within the measured motion at its location (the relative displacement of
the period-averaged validation record, integrated as the library integrates velocity and
acceleration: zero mean, lines below half the band's lower edge dropped), whatever its
``side`` says: a gap beyond the motion is never touched. A hidden clearance is two-sided
by construction (both gaps inside the linear motion), a hidden stop has one side open.

Per case:

- *top-1 right* (cases with an effect): the first diagnosis finds something and its top
  candidate names the kind and location of a hidden effect;
- *floor reached* (cases with an effect): the last revision's validation error is within
  twice the noise floor;
- *false alarm* (cases without an effect): the first diagnosis claims anything;
- *pair found* (two effects): the rounds' top candidates, with the partner a top
  candidate is claimed together with, name both effects;
- *nothing found above the floor*: a diagnosis found nothing while its revision's
  validation error exceeded three times the noise floor (any case).

Not scored but listed, because it explains many failures: revision 0 (the library's
linear model) missing the validation data by clearly more than the true linear structure
does (more than 1.5 times its error plus twice the noise floor): the linear
identification, not the diagnosis, then sets what the loop can reach.
"""

from __future__ import annotations

import json
import math
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from benchmarks.generalisation.blind import (
    cases_dir,
    read_answers,
    require_answers,
    truth_path,
)
from benchmarks.generalisation.scoring import bin_label

FLOOR_FACTOR = 2.0
NOTHING_FACTOR = 3.0
LINEAR_FACTOR = 1.5


@dataclass
class HiddenScore:
    """The score of one hidden-effect case (module docstring).

    Attributes
    ----------
    case : str
    plan : dict
        The drawn settings (:func:`.hidden.draw_hidden_case`).
    effects : int
        Hidden effects (0, 1 or 2).
    status : str
        "ok" or "error" (the library refused or crashed).
    top1 : bool
    floor_reached : bool
    false_alarm : bool
    pair_found : bool
    nothing_above_floor : bool
    diagnosis_s : list of float
        Wall time of every diagnosis [s].
    final_pct, floor_pct, before_pct : float
        Last revision's and revision 0's validation NRMSE, and the noise floor [%].
    problems : list of (str, str)
        (category, detail) of everything that went wrong.
    warnings : list of str
        The study's warnings (:attr:`fnsi.study.Study.warnings`: e.g. inputs its
        realisations do not tell apart), listed beside a failure.
    """

    case: str
    plan: dict
    effects: int
    status: str
    top1: bool = False
    floor_reached: bool = False
    false_alarm: bool = False
    pair_found: bool = False
    nothing_above_floor: bool = False
    diagnosis_s: list[float] = field(default_factory=list)
    final_pct: float = math.inf
    floor_pct: float = math.nan
    before_pct: float = math.inf
    problems: list[tuple[str, str]] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)


def _dof(name: str | None) -> int:
    """DOF of an output name ``x<k>`` (-1: ground)."""
    return -1 if name is None else int(name[1:])


def claim(candidate: dict, motion: dict[str, np.ndarray] | None = None,
          ) -> tuple[str, frozenset, str | None]:
    """Kind class, location and stop side (in the truth's orientation, see :func:`_side`)
    of a diagnosis candidate (its JSON).

    Parameters
    ----------
    candidate : dict
        The candidate's JSON.
    motion : dict of str to ndarray, optional
        Measured displacement of each output (:func:`measured_motion`): which gaps of a
        claimed clearance the motion reaches (without it, the element's ``side``).
    """
    element = candidate.get("element") or {}
    kind = candidate["effect"]
    location = candidate.get("location")
    if location is None:
        return kind, frozenset(), None
    side = None
    if kind == "clearance":
        side = _contact_side(element, motion, location)
        kind = "clearance" if side is None else "stop"
    dof, ref = _dof(location["dof"]), _dof(location["ref"])
    return kind, frozenset((dof, ref)), None if side is None else _side(side, dof, ref)


def _contact_side(element: dict, motion: dict[str, np.ndarray] | None,
                  location: dict) -> str | None:
    """The side of a clearance that alone is in contact, or None (both or neither)."""
    gap = element.get("gap")
    gaps = {"negative": element.get("gap_negative", gap),
            "positive": element.get("gap_positive", gap)}
    side = element.get("side", "both")
    if side != "both":
        gaps["negative" if side == "positive" else "positive"] = None
    if motion is not None:
        x = motion[location["dof"]] - (0.0 if location["ref"] is None
                                       else motion[location["ref"]])
        reach = {"negative": -x.min(), "positive": x.max()}
        gaps = {k: g if g is not None and g < reach[k] else None for k, g in gaps.items()}
    touched = [k for k, g in gaps.items() if g is not None]
    return touched[0] if len(touched) == 1 else None


def measured_motion(path: Path, band: tuple[float, float]) -> dict[str, np.ndarray]:
    """Displacement of every output over the period-averaged validation record of a case
    file (velocity and acceleration integrated on the DFT lines, zero mean and the lines
    below half the band's lower edge dropped, as the library's screening does)."""
    with np.load(path, allow_pickle=False) as data:
        y, periods = data["y_validation"][0], int(data["periods"])
        fs, quantity = float(data["fs"]), str(data["quantity"])
        names = [str(n) for n in data["output_names"]]
    mean = y.reshape(periods, -1, y.shape[1]).mean(axis=0)
    if quantity != "displacement":
        spectrum = np.fft.rfft(mean, axis=0)
        f = np.fft.rfftfreq(mean.shape[0], 1.0 / fs)
        power = 1 if quantity == "velocity" else 2
        keep = (f >= 0.5 * band[0]) & (f > 0)
        spectrum[keep] /= (2j * np.pi * f[keep, None]) ** power
        spectrum[~keep] = 0.0
        mean = np.fft.irfft(spectrum, n=mean.shape[0], axis=0)
    return {name: mean[:, k] for k, name in enumerate(names)}


def _side(side: str, dof: int, ref: int) -> str:
    """A stop's side for the orientation (larger DOF minus smaller, or DOF minus ground):
    the same contact reads "positive" from one end and "negative" from the other."""
    if ref == -1 or dof > ref:
        return side
    return "negative" if side == "positive" else "positive"


def truth_claim(element: dict) -> tuple[str, frozenset, str | None]:
    """The same triple for a hidden element of the truth."""
    dof, ref = element["dof"], element["ref"]
    side = None
    if element["kind_class"] == "stop":
        side = _side("positive" if math.isinf(element["gaps"][0]) else "negative", dof, ref)
    return element["kind_class"], frozenset((dof, ref)), side


WARNING_CHARS = 200
"""Characters of each study warning a failure's entry quotes."""


def _words(triple: tuple[str, frozenset, str | None]) -> str:
    kind, location, side = triple
    where = "-".join("ground" if d == -1 else f"x{d}" for d in sorted(location, reverse=True))
    return f"{kind}{'' if side is None else ' ' + side} at {where or 'no location'}"


def _estimation_words(answer: dict, plan: dict) -> str:
    """Revision 0's error on the estimation record against the true linear structure's,
    where both are known: lower than the truth's there while higher on validation, the
    model fitted what the estimation record alone holds (answers and truths of older
    runs lack the figures: nothing is said)."""
    fitted, truth = answer.get("estimation_pct"), plan.get("linear_estimation_error_pct")
    if fitted is None or truth is None:
        return ""
    return f"; estimation record {_number(fitted):.3g} % against {truth:.3g} %"


def score_hidden_case(case: str, truth: dict, answer: dict,
                      motion: dict[str, np.ndarray] | None = None) -> HiddenScore:
    """Score one study loop's answer against its truth (module docstring); ``motion``:
    :func:`measured_motion` of the case."""
    plan = truth["plan"]
    score = HiddenScore(case, plan, plan["effects"], answer["status"])
    rounds = answer["rounds"]
    score.diagnosis_s = [r["diagnosis_s"] for r in rounds]
    if answer["status"] != "ok":
        score.problems.append(("refused or crashed", answer["error"].splitlines()[0][:160]))
        return score
    hidden = [truth_claim(e) for e in truth["elements"]]
    revisions = answer["revisions"]
    score.warnings = list(answer.get("warnings", []))   # older answers have none
    score.floor_pct = _number(answer["noise_floor_pct"])
    score.before_pct = _number(revisions[0]["nrmse_pct"])
    score.final_pct = _number(revisions[-1]["nrmse_pct"])
    truth_linear = plan["linear_error_pct"]
    if score.before_pct > LINEAR_FACTOR * truth_linear + FLOOR_FACTOR * score.floor_pct:
        score.problems.append(("revision 0 worse than the true linear structure",
                               f"{score.before_pct:.3g} % against {truth_linear:.3g} % "
                               f"(order {revisions[0]['order']}"
                               + (f"; {revisions[0]['failure']}" if revisions[0]["failure"]
                                  else "") + ")" + _estimation_words(answer, plan)))
    claims = [claim(c, motion) for r in rounds if r["found"] for c in _claimed(r)]
    for r in rounds:
        before = _number(r["nrmse_before_pct"])
        if not r["found"] and before > NOTHING_FACTOR * score.floor_pct:
            score.nothing_above_floor = True
            score.problems.append(("nothing found above the floor",
                                   f"error {before:.3g} %, floor {score.floor_pct:.3g} %: "
                                   + r["summary"][:300]))
    if not hidden:
        score.false_alarm = bool(claims)
        if claims:
            score.problems.append(("false alarm", _words(claims[0]) + f" (error "
                                   f"{score.before_pct:.3g} % -> {score.final_pct:.3g} %)"))
        return score
    score.top1 = bool(claims) and claims[0] in hidden
    score.floor_reached = score.final_pct <= FLOOR_FACTOR * score.floor_pct
    score.pair_found = len(hidden) == 2 and set(hidden) <= set(claims)
    truth_words = " + ".join(_words(h) for h in hidden)
    if not claims:
        score.problems.append(("nothing claimed", f"true {truth_words}"))
    elif not score.top1:
        score.problems.append((_miss_category(claims[0], hidden),
                               f"claimed {_words(claims[0])}; true {truth_words}"))
    invented = _beyond_truth(claims, hidden)
    if invented:
        score.problems.append(("claimed beyond the truth", "claimed " + " then ".join(
            _words(c) for c in invented) + f" once the true {truth_words} "
            f"{'was' if len(hidden) == 1 else 'were'} claimed (error "
            f"{score.before_pct:.3g} % -> {score.final_pct:.3g} %, floor "
            f"{score.floor_pct:.3g} %)"))
    if len(hidden) == 2 and not score.pair_found:
        score.problems.append(("pair not completed", "claimed " + (" then ".join(
            _words(c) for c in claims) or "nothing") + f"; true {truth_words}"))
    if not score.floor_reached:
        score.problems.append(("floor not reached",
                               f"{score.before_pct:.3g} % -> {score.final_pct:.3g} % "
                               f"(floor {score.floor_pct:.3g} %) with "
                               f"{' then '.join(r['note'] for r in revisions[1:]) or 'nothing'}"))
    return score


def _claimed(round_: dict) -> list[dict]:
    """What a round that found something claims: its top candidate, then the partner it
    was claimed together with (older answers have no ``partner``)."""
    top = round_["candidates"][0]
    return [top] + ([top["partner"]] if top.get("partner") else [])


def _beyond_truth(claims: list[tuple], hidden: list[tuple]) -> list[tuple]:
    """The claims made after every hidden effect was already claimed: what the loop
    invented once the truth was in the model (the loop's rounds stop only when nothing
    more is claimed)."""
    for count in range(len(claims)):
        if set(hidden) <= set(claims[:count]):
            return claims[count:]
    return []


def _miss_category(claimed: tuple, hidden: list[tuple]) -> str:
    """Which part of the top claim is wrong."""
    if claimed[0] == "missing_mode":
        return "missing mode claimed"
    if any(claimed[1] == h[1] for h in hidden):
        return "wrong kind"
    if any(claimed[0] == h[0] and claimed[1] != h[1] for h in hidden):
        return "wrong location"
    return "wrong kind and location"


def _number(value) -> float:
    """A JSON number of the answer (null: not finite)."""
    return math.inf if value is None else float(value)


def score_hidden(root: Path, progress: Callable[[str], None] | None = None,
                 ) -> list[HiddenScore]:
    """Score every case of ``root`` (phase 3): refuses until every answer is on disk."""
    cases = require_answers(root)
    answers = read_answers(root, cases)
    truth = json.loads(truth_path(root).read_text())["cases"]
    if progress is not None:
        progress(f"scoring {len(cases)} answers")
    return [score_hidden_case(c, truth[c], answers[c], measured_motion(
        cases_dir(root) / f"{c}.npz", truth[c]["plan"]["band_hz"])) for c in cases]


# -- the table -------------------------------------------------------------------------------

def _pct(flags: list[bool]) -> float | None:
    return round(100 * float(np.mean(flags)), 1) if flags else None


def summary(scores: list[HiddenScore]) -> dict:
    """The headline numbers (the benchmark's last output line)."""
    effect = [s for s in scores if s.effects]
    times = [t for s in scores for t in s.diagnosis_s]
    return {"cases": len(scores),
            "top1_kind_location_pct": _pct([s.top1 for s in effect]),
            "floor_reached_pct": _pct([s.floor_reached for s in effect]),
            "false_alarm_pct": _pct([s.false_alarm for s in scores if not s.effects]),
            "two_effect_found_pct": _pct([s.pair_found for s in scores if s.effects == 2]),
            "nothing_found_above_floor": sum(s.nothing_above_floor for s in scores),
            "median_diagnosis_s": round(float(np.median(times)), 2) if times else None}


def _kind_label(plan: dict) -> str:
    return {0: "no effect", 2: "two effects"}.get(plan["effects"], plan["kinds"][0]
                                                  if plan["kinds"] else "no effect")


#: Breakdowns of the table: name and the label(s) of a case's plan.
GROUPS: tuple[tuple[str, Callable[[dict], list[str]]], ...] = (
    ("kind", lambda p: [_kind_label(p)]),
    ("kind (every effect, pairs included)", lambda p: p["kinds"] or ["no effect"]),
    ("location", lambda p: p["locations"] or ["no effect"]),
    ("noise", lambda p: [bin_label(p["noise_pct"], (0, 0.1, 0.5, 2, 5), " %")]),
    ("fs / band edge", lambda p: [bin_label(p["fs_ratio"], (4, 10, 20, 40))]),
    ("output", lambda p: [p["quantity"]]),
    ("linear error", lambda p: [bin_label(p["linear_error_pct"], (0, 3, 10, 30, 60), " %")]),
)


def _cell(flags: list[bool]) -> str:
    return "-" if not flags else f"{100 * np.mean(flags):.0f} % ({sum(flags)}/{len(flags)})"


def _row(label: str, group: list[HiddenScore]) -> str:
    effect = [s for s in group if s.effects]
    times = [t for s in group for t in s.diagnosis_s]
    return (f"| {label} | {len(group)} | {_cell([s.top1 for s in effect])} | "
            f"{_cell([s.floor_reached for s in effect])} | "
            f"{_cell([s.false_alarm for s in group if not s.effects])} | "
            f"{_cell([s.pair_found for s in group if s.effects == 2])} | "
            f"{sum(s.nothing_above_floor for s in group)} | "
            f"{sum(s.status != 'ok' for s in group)} | "
            f"{np.median(times) if times else math.nan:.1f} |")


def report(scores: list[HiddenScore], seed: int, header: str,
           skipped: dict[str, str] | None = None, provenance: str = "") -> str:
    """The results table in Markdown: totals, breakdowns, failure categories, failures;
    ``skipped``: cases the generator could not draw and why (the index's "skipped");
    ``provenance``: the case files' and the machine's paragraph
    (:func:`.provenance.provenance_words`)."""
    head = summary(scores)
    lines = [header, "", f"Seed {seed}, {head['cases']} cases. Headline: `{json.dumps(head)}` "
             "(targets: top-1 >= 95 %, floor reached >= 90 %, false alarms <= 2 %, pairs "
             ">= 90 %, nothing found above the floor: 0).", ""]
    if provenance:
        lines += [provenance, ""]
    if skipped:
        lines += [f"Not drawn ({len(skipped)}, effects that could not be sized into the "
                  "band, not scored): " + "; ".join(f"{c}: {r}" for c, r in
                                                     sorted(skipped.items())) + ".", ""]
    columns = ("| {} | cases | top-1 kind and location | floor reached | false alarm | pair "
               "found | nothing found above floor | refused | median diagnosis s |\n"
               "|---|---|---|---|---|---|---|---|---|")
    lines += [columns.format("all"), _row("all", scores), ""]
    for name, labels in GROUPS:
        lines.append(columns.format(name))
        groups: dict[str, list[HiddenScore]] = {}
        for s in scores:
            for label in labels(s.plan):
                groups.setdefault(label, []).append(s)
        lines += [_row(k, groups[k]) for k in sorted(groups)]
        lines.append("")
    cases = Counter(kind for s in scores for kind in {k for k, _ in s.problems})
    lines += ["## Failure categories", "", "| category | cases |", "|---|---|"]
    lines += [f"| {k} | {v} |" for k, v in cases.most_common()]
    lines += ["", "## Failures", ""]
    for s in scores:
        if not s.problems:
            continue
        p = s.plan
        effects = ", ".join(f"{k} ({w})" for k, w in zip(p["kinds"], p["locations"],
                                                       strict=True))
        lines.append(f"- **{s.case}** {p['topology']} {p['dofs']} DOFs, {p['damping']}"
                     f"{', close modes' if p['close_modes'] else ''}, {p['quantity']}, "
                     f"{p['inputs']} in / {p['sensors']} out, noise {p['noise_pct']:.2g} %, "
                     f"fs {p['fs_ratio']:.3g}x; hidden "
                     f"{effects or 'nothing'}"
                     f", linear error {p['linear_error_pct']:.3g} %")
        lines += [f"  - {kind}: {detail}" for kind, detail in s.problems]
        lines += [f"  - the study warned: {w[:WARNING_CHARS]}" for w in s.warnings]
    return "\n".join(lines) + "\n"
