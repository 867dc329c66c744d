"""Benchmark: does the diagnosis survive a perturbation far below the noise? (issue 21)

The same hidden-effect case, run on two machines, gave different diagnoses (seed 21 case
9: a quadratic spring claimed on one CPU, nothing on another) although every BLAS kernel
of one machine agrees. A result that moves with the last bits of the data moves with the
machine. This benchmark measures how far: each case of a generalisation work directory
(``benchmarks/generalisation.py --part hidden --phase generate``) is studied and
diagnosed once as recorded and ``--draws`` times with both records' outputs multiplied by
1 + ``--relative`` x N(0, 1) per sample (1e-12: some 4500 times the rounding of a
double, a billionth of the smallest noise level drawn), each draw seeded.

Per case it prints revision 0's order and error, the three best screened locations and
the best stage-2 proposal of each run, the claim, and the largest shift of a location's
screening reduction between the runs. The truth is never read. The last line is one JSON
object::

    {"cases", "relative", "draws", "revision0_changed", "top3_changed",
     "proposal_changed", "claim_changed", "median_max_reduction_shift"}

where each ``*_changed`` counts the cases in which some perturbed run differs from the
recorded one.

Run: ``OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/diagnosis_sensitivity.py
--workdir D [--cases 12] [--draws 2] [--jobs 2]`` (about a minute per run of a case).
"""

from __future__ import annotations

import argparse
import json
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # this checkout's fnsi and benchmarks, not an installed copy

from benchmarks.generalisation.runner import _measurement  # noqa: E402
from fnsi.identification import IdentificationSettings  # noqa: E402
from fnsi.study import Study, law_name  # noqa: E402


def perturbed(data: dict[str, np.ndarray], relative: float, seed: int
              ) -> dict[str, np.ndarray]:
    """The case's arrays with both records' outputs multiplied by 1 + relative N(0, 1)."""
    rng = np.random.default_rng(seed)
    return {k: (v * (1.0 + relative * rng.standard_normal(v.shape))
                if k in ("y", "y_validation") else v) for k, v in data.items()}


def diagnosed(task: tuple[Path, float, int]) -> dict:
    """Revision 0 and its diagnosis of one (possibly perturbed) run of a case."""
    path, relative, seed = task
    with np.load(path, allow_pickle=False) as stored:
        data = {k: stored[k] for k in stored.files}
    if relative > 0:
        data = perturbed(data, relative, seed)
    band = tuple(float(b) for b in data["band"])
    study = Study.create(_measurement(data), _measurement(data, "_validation"),
                         IdentificationSettings(band=band))
    diagnosis = study.diagnose()
    top = diagnosis.candidates[0] if diagnosis.candidates else None
    return {"order": study.revisions[0].identified_order,
            "nrmse_pct": study.revisions[0].nrmse_percent,
            "locations": {s.location.label: s.reduction for s in diagnosis.locations},
            "top3": [s.location.label for s in diagnosis.locations[:3]],
            "proposal": (law_name(diagnosis.proposals[0].element) if diagnosis.proposals
                         else "none"),
            "claim": ("nothing" if not diagnosis.found or top is None
                      else "one more mode" if top.element is None
                      else law_name(top.element))}


def compare(runs: list[dict]) -> dict:
    """What changed between the recorded run (first) and the perturbed ones."""
    first, rest = runs[0], runs[1:]
    # every run screens the same locations (those of the case's outputs)
    shift = max((abs(r["locations"][label] - value)
                 for r in rest for label, value in first["locations"].items()),
                default=0.0)
    return {"revision0": any(r["order"] != first["order"]
                             or abs(r["nrmse_pct"] - first["nrmse_pct"])
                             > 1e-6 * first["nrmse_pct"] for r in rest),
            "top3": any(r["top3"] != first["top3"] for r in rest),
            "proposal": any(r["proposal"] != first["proposal"] for r in rest),
            "claim": any(r["claim"] != first["claim"] for r in rest),
            "max_reduction_shift": float(shift)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workdir", type=Path, required=True,
                        help="generalisation work directory holding cases/*.npz")
    parser.add_argument("--cases", type=int, default=12, help="first cases by name")
    parser.add_argument("--draws", type=int, default=2)
    parser.add_argument("--relative", type=float, default=1e-12)
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args()
    paths = sorted((args.workdir / "cases").glob("case*.npz"))[: args.cases]
    if not paths:
        parser.error(f"no cases under {args.workdir / 'cases'}: generate them first")
    tasks = [(p, args.relative if d else 0.0, d) for p in paths for d in range(args.draws + 1)]
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        results = list(pool.map(diagnosed, tasks))
    changes = []
    for k, path in enumerate(paths):
        runs = results[k * (args.draws + 1): (k + 1) * (args.draws + 1)]
        change = compare(runs)
        changes.append(change)
        print(f"{path.stem}: max reduction shift {change['max_reduction_shift']:.2g}")
        for r in runs:
            print(f"  order {r['order']} {r['nrmse_pct']:.6g} %; top {', '.join(r['top3'])};"
                  f" proposal {r['proposal']}; claim {r['claim']}")
    print(json.dumps({"cases": len(paths), "relative": args.relative, "draws": args.draws,
                      **{f"{key}_changed": sum(c[key] for c in changes)
                         for key in ("revision0", "top3", "proposal", "claim")},
                      "median_max_reduction_shift": float(np.median(
                          [c["max_reduction_shift"] for c in changes]))}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
