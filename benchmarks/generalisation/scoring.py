"""Phase 3: score the recorded answers against the sealed truth, and tabulate.

Opened only after :func:`.blind.require_answers` has found every answer on disk.

Per case (issue 20):

- a true mode and a reported one *match* when the frequency is within 0.5 % and the
  damping ratio within 10 % (relative); modes are paired one to one (an assignment
  minimising the normalised distance over admissible pairs), so one reported mode cannot
  stand for two close true modes;
- every *required* mode (in the band, at least 1 % of the response power) must match;
- a reported mode in the band that matches nothing is *spurious*, unless it is the only
  report near (0.5 % in frequency) a true mode that is not required (a weakly excited
  real mode estimated poorly is not a spurious one); a second report near a matched mode
  is a *duplicate*, counted as spurious;
- the order is *correct* when every required mode matches and nothing is spurious;
- the model is *simulable* when its discrete-time poles are inside the unit circle; an
  unsimulable model must come with a warning.
"""

from __future__ import annotations

import itertools
import json
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.optimize

from benchmarks.generalisation.blind import read_answers, require_answers, truth_path

FREQUENCY_TOLERANCE = 0.005
DAMPING_TOLERANCE = 0.10


@dataclass
class Score:
    """The score of one case.

    Attributes
    ----------
    case : str
    plan : dict
        The drawn settings (:func:`.cases.draw_case`).
    required, found : int
        Required modes, and how many of them matched.
    spurious : int
        Spurious and duplicate reports in the band.
    status : str
        "ok" or "error" (the library refused or crashed).
    simulable : bool
    warned : bool
        The library raised a warning.
    identify_s : float
        Wall time of the identification [s].
    problems : list of (str, str)
        (category, detail) of everything that went wrong.
    orders_all, orders_confirmed : list of int
        Orders of the stabilisation diagram at which every pole (every confirmed pole)
        would have made the answer correct: the orders a perfect order choice could take.
    """

    case: str
    plan: dict
    required: int
    found: int
    spurious: int
    status: str
    simulable: bool
    warned: bool
    identify_s: float
    problems: list[tuple[str, str]] = field(default_factory=list)
    orders_all: list[int] = field(default_factory=list)
    orders_confirmed: list[int] = field(default_factory=list)

    @property
    def achievable(self) -> bool:
        """Some order of the diagram (all its poles, or its confirmed ones) is correct."""
        return bool(self.orders_all or self.orders_confirmed)

    @property
    def correct(self) -> bool:
        """Order correct: ran, every required mode found, nothing spurious."""
        return self.status == "ok" and self.found == self.required and self.spurious == 0


def _relative(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.abs(a[:, None] - b[None, :]) / b[None, :]


def match(true_f: np.ndarray, true_z: np.ndarray, f: np.ndarray, z: np.ndarray,
          ) -> dict[int, int]:
    """One-to-one pairs {true index: reported index} within the tolerances."""
    if true_f.size == 0 or f.size == 0:
        return {}
    df = _relative(f, true_f).T / FREQUENCY_TOLERANCE  # (true, reported)
    dz = _relative(z, true_z).T / DAMPING_TOLERANCE
    ok = (df <= 1) & (dz <= 1)
    cost = np.where(ok, df**2 + dz**2, 1e6)
    rows, cols = scipy.optimize.linear_sum_assignment(cost)
    return {int(r): int(c) for r, c in zip(rows, cols, strict=True) if ok[r, c]}


def score_case(case: str, truth: dict, answer: dict) -> Score:
    """Score one answer against its truth (see the module docstring)."""
    plan = truth["plan"]
    modes = truth["modes"]
    score = Score(case, plan, sum(m["required"] for m in modes), 0, 0, answer["status"], True,
                  bool(answer.get("warnings")), float(answer["identify_s"]))
    if answer["status"] != "ok":
        score.problems.append(("refused or crashed", answer["error"].splitlines()[0][:160]))
        return score
    score.simulable = answer["max_pole_modulus"] < 1.0
    if not score.simulable:
        score.problems.append(("unsimulable" + ("" if score.warned else " without warning"),
                               f"largest pole modulus {answer['max_pole_modulus']:.6f}"))
    score.found, score.spurious, problems = compare(modes, plan["band_hz"], answer["modes"])
    score.problems += problems
    for entry in answer["diagram"]:
        for kept, orders in ((entry["modes"], score.orders_all),
                             ([m for m in entry["modes"] if m["confirmed"]],
                              score.orders_confirmed)):
            found, spurious, _ = compare(modes, plan["band_hz"], kept)
            if found == score.required and spurious == 0:
                orders.append(entry["order"])
    return score


def compare(modes: list[dict], band: tuple[float, float], reported: list[dict],
            ) -> tuple[int, int, list[tuple[str, str]]]:
    """Required modes found, spurious reports in the band, and (category, detail) of each
    problem, for ``reported`` modes (dicts with frequency_hz and damping_ratio) against
    the true ``modes`` (see the module docstring)."""
    true_f = np.array([m["frequency_hz"] for m in modes])
    true_z = np.array([m["damping_ratio"] for m in modes])
    f = np.array([m["frequency_hz"] for m in reported])
    z = np.array([m["damping_ratio"] for m in reported])
    pairs = match(true_f, true_z, f, z)
    required = [k for k, m in enumerate(modes) if m["required"]]
    found = sum(k in pairs for k in required)
    problems = [_miss(modes[k], f, z) for k in required if k not in pairs]
    near = (_relative(f, true_f) <= FREQUENCY_TOLERANCE) if f.size else np.zeros((0, 0), bool)
    excused: set[int] = set()
    spurious = 0
    for j in range(f.size):
        if j in pairs.values() or not band[0] <= f[j] < band[1]:
            continue
        close = np.flatnonzero(near[j])
        weak = [k for k in close if k not in pairs and not modes[k]["required"]
                and k not in excused]
        if weak:
            excused.add(weak[0])
            continue
        spurious += 1
        nearest = int(np.argmin(np.abs(true_f - f[j]) / true_f))
        problems.append(("duplicate" if close.size else "spurious",
                         f"reported {f[j]:.4g} Hz, zeta {100 * z[j]:.3g} %; nearest true "
                         f"{true_f[nearest]:.4g} Hz ({_pct(f[j], true_f[nearest])} in f)"))
    return found, spurious, problems


def _pct(value: float, truth: float) -> str:
    return f"{100 * (value - truth) / truth:+.2f} %"


def _miss(mode: dict, f: np.ndarray, z: np.ndarray) -> tuple[str, str]:
    """Category and detail of a required mode without a match."""
    ft, zt = mode["frequency_hz"], mode["damping_ratio"]
    what = (f"true {ft:.4g} Hz, zeta {100 * zt:.3g} %, "
            f"{100 * mode['power_share']:.1f} % of the power")
    if f.size == 0:
        return "missed", what + "; nothing reported"
    j = int(np.argmin(np.abs(f - ft)))
    got = f"; nearest report {f[j]:.4g} Hz ({_pct(f[j], ft)}), zeta {_pct(z[j], zt)}"
    if abs(f[j] - ft) <= FREQUENCY_TOLERANCE * ft:
        return "damping off", what + got
    if abs(f[j] - ft) <= 0.05 * ft:
        return "frequency off", what + got
    return "missed", what + got


def score_all(root: Path, progress: Callable[[str], None] | None = None) -> list[Score]:
    """Score every case of ``root`` (phase 3): refuses until every answer is on disk."""
    cases = require_answers(root)
    answers = read_answers(root, cases)
    truth = json.loads(truth_path(root).read_text())["cases"]
    if progress is not None:
        progress(f"scoring {len(cases)} answers")
    return [score_case(c, truth[c], answers[c]) for c in cases]


# -- the table -------------------------------------------------------------------------------

def bin_label(value: float, edges: tuple[float, ...], unit: str = "") -> str:
    """Label of the bin [low, high) of ``value`` among consecutive ``edges`` (the last bin
    takes what rounding puts at or just above its upper edge)."""
    low, high = next((pair for pair in itertools.pairwise(edges) if value < pair[1]),
                     edges[-2:])
    return f"{low:g}-{high:g}{unit}"


def _count_bin(value: int, edges: tuple[int, ...]) -> str:
    """Label of the bin low..high - 1 of a count among consecutive ``edges``."""
    low, high = next(pair for pair in itertools.pairwise(edges) if value < pair[1])
    return str(low) if high == low + 1 else f"{low}-{high - 1}"


#: Breakdowns of the table: name and the label of a case's plan.
GROUPS: tuple[tuple[str, Callable[[dict], str]], ...] = (
    ("topology", lambda p: p["topology"]),
    ("DOFs", lambda p: _count_bin(p["dofs"], (2, 5, 9, 13))),
    ("damping", lambda p: p["damping"]),
    ("close modes", lambda p: "yes" if p["close_modes"] else "no"),
    ("noise", lambda p: bin_label(p["noise_pct"], (0, 0.1, 0.5, 2, 5), " %")),
    ("fs / band edge", lambda p: bin_label(p["fs_ratio"], (4, 10, 20, 40))),
    ("output", lambda p: p["quantity"]),
    ("inputs", lambda p: str(p["inputs"])),
    ("sensors", lambda p: _count_bin(p["sensors"], (1, 2, 5, 9))),
    ("realisations", lambda p: str(p["realisations"])),
)


def summary(scores: list[Score]) -> dict:
    """The headline numbers (the benchmark's last output line)."""
    return {"structures": len(scores),
            "order_correct_pct": round(100 * np.mean([s.correct for s in scores]), 1),
            "unsimulable": sum(not s.simulable and not s.warned for s in scores),
            "median_identify_s": round(float(np.median([s.identify_s for s in scores])), 3)}


def _row(label: str, group: list[Score]) -> str:
    required = sum(s.required for s in group)
    found = sum(s.found for s in group)
    return (f"| {label} | {len(group)} | {100 * np.mean([s.correct for s in group]):.0f} % | "
            f"{100 * np.mean([s.achievable for s in group]):.0f} % | "
            f"{found}/{required} | {sum(s.spurious for s in group)} | "
            f"{sum(s.status != 'ok' for s in group)} | "
            f"{np.median([s.identify_s for s in group]):.2f} |")


def _orders(score: Score) -> str:
    """Which orders of the diagram would have been correct, in words."""
    if not score.achievable:
        return "no order of the diagram correct"
    return (f"correct at orders {_runs(score.orders_all)} (all poles), "
            f"{_runs(score.orders_confirmed)} (confirmed poles)")


def _runs(orders: list[int]) -> str:
    """Orders as runs of consecutive even orders: [2, 4, 6, 10] -> "2-6, 10"."""
    if not orders:
        return "none"
    runs = [[orders[0], orders[0]]]
    for order in orders[1:]:
        if order == runs[-1][1] + 2:
            runs[-1][1] = order
        else:
            runs.append([order, order])
    return ", ".join(f"{a}" if a == b else f"{a}-{b}" for a, b in runs)


def report(scores: list[Score], seed: int, header: str) -> str:
    """The results table in Markdown: totals, breakdowns, failure categories, failures."""
    head = summary(scores)
    lines = [header, "",
             f"Seed {seed}, {head['structures']} linear structures: order correct on "
             f"**{head['order_correct_pct']} %** (target 95 %); "
             f"{sum(not s.simulable for s in scores)} unsimulable models, "
             f"{head['unsimulable']} of them without a warning; median identification "
             f"{head['median_identify_s']} s. Some order of the stabilisation diagram "
             f"would have been correct (with all its poles or with its confirmed ones) on "
             f"{100 * np.mean([s.achievable for s in scores]):.1f} % (*some order correct*: "
             "the ceiling of a perfect order choice with the library's estimates).", ""]
    columns = ("| {} | cases | order correct | some order correct | required modes found | "
               "spurious | refused | median s |\n|---|---|---|---|---|---|---|---|")
    lines += [columns.format("all"), _row("all", scores), ""]
    for name, label in GROUPS:
        lines.append(columns.format(name))
        groups: dict[str, list[Score]] = {}
        for s in scores:
            groups.setdefault(label(s.plan), []).append(s)
        lines += [_row(k, groups[k]) for k in sorted(groups)]
        lines.append("")
    categories = Counter(kind for s in scores for kind, _ in s.problems)
    cases = Counter(kind for s in scores for kind in {k for k, _ in s.problems})
    lines += ["## Failure categories", "", "| category | occurrences | cases |", "|---|---|---|"]
    lines += [f"| {k} | {v} | {cases[k]} |" for k, v in categories.most_common()]
    lines += ["", "## Failures", ""]
    for s in scores:
        if s.correct and s.simulable:
            continue
        p = s.plan
        lines.append(f"- **{s.case}** {p['topology']} {p['dofs']} DOFs, {p['damping']}"
                     f"{', close modes' if p['close_modes'] else ''}, {p['quantity']}, "
                     f"{p['inputs']} in / {p['sensors']} out, noise {p['noise_pct']:.2g} %, "
                     f"fs {p['fs_ratio']:.3g}x, band {p['band_hz'][0]:.4g}-"
                     f"{p['band_hz'][1]:.4g} Hz: found {s.found}/{s.required}; "
                     + _orders(s))
        lines += [f"  - {kind}: {detail}" for kind, detail in s.problems]
    return "\n".join(lines) + "\n"
