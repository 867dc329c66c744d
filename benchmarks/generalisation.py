"""Generalisation benchmark: random structures identified blind (linear part, issue 20)
and hidden effects diagnosed blind (``--part hidden``, issue 21).

Linear part: three phases (:mod:`benchmarks.generalisation`):

1. generate: draw ``--count`` structures and tests from ``--seed``
   (:mod:`benchmarks.generalisation.cases`: chains, trees, grids of 2-12 DOFs, damping
   0.5-10 % proportional or not, close modes, 1-2 inputs, sensors on a subset, noise
   0.1-5 %, fs 4-40 x the band edge, displacement, velocity or acceleration), synthesised
   exactly in the frequency domain with numpy alone; the truth is sealed;
2. run: :func:`fnsi.identification.identify` with its defaults on each case's data,
   under a blindfold that refuses to open the truth; every answer written to disk;
3. score: refused until every answer is on disk; then the truth is read, and the table
   (by topology, DOFs, damping, close modes, noise, fs ratio, output, inputs, sensors,
   realisations) and every failure go to ``--results``.

Last output line: one JSON object {"structures", "order_correct_pct", "unsimulable",
"median_identify_s"} ("unsimulable": models with a pole outside the unit circle returned
without a warning).

Run: ``.venv/bin/python benchmarks/generalisation.py`` (200 cases, seed 20, writes
benchmarks/results/generalisation.md); ``--smoke`` for the first 30 cases without
touching the results file. Case k depends only on the seed and k, so a smoke run is
the first 30 cases of the full one. To compare two versions of the library on the same
files: ``--phase generate --workdir D`` once, then per version a copy of D with
``--phase run`` and ``--phase score`` (the table goes to the copy). ``--noise-free``
draws the same cases without measurement noise: some order of the diagram must then be
correct on every case (100 % on seed 20), which checks the generator's truth against its
data.

Hidden-effect part (``--part hidden``, default 150 cases, seed 21): the same structures
and tests with shorter records and 0, 1 or 2 hidden nonlinear elements (cubic hardening
and softening, quadratic stiffness, symmetric and asymmetric clearances, one-sided stops,
Coulomb friction, quadratic damping; to ground or between measured DOFs, near or far from
the input), each sized so that the true linear structure misses the validation response,
and the estimation response it is identified from, by 3-60 %
(:mod:`benchmarks.generalisation.hidden`, scipy's integrator to periodic steady state); the
library's study loop with its defaults (create, diagnose, add the top
candidate, diagnose, add) on each, blind; scored by
:mod:`benchmarks.generalisation.hidden_scoring` into
benchmarks/results/generalisation_hidden.md. ``--phase oracle``, once answered: the true
elements added by the library, which tells a diagnosis-limited failure from an
identification-limited one (:mod:`benchmarks.generalisation.oracle`; last line
{"cases", "loop_floor_reached", "oracle_floor_reached", "diagnosis_limited",
"identification_limited"}). ``--smoke``: the first 10 cases. ``--jobs``
processes generate and run cases in parallel (default 2). Last output line: one JSON
object {"cases", "top1_kind_location_pct", "floor_reached_pct", "false_alarm_pct",
"two_effect_found_pct", "nothing_found_above_floor", "median_diagnosis_s"}.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # this checkout's fnsi and benchmarks, not an installed copy

from benchmarks.generalisation import hidden_scoring  # noqa: E402
from benchmarks.generalisation.blind import read_answers, read_index  # noqa: E402
from benchmarks.generalisation.cases import generate  # noqa: E402
from benchmarks.generalisation.hidden import generate_hidden  # noqa: E402
from benchmarks.generalisation.oracle import oracle_report, run_oracle  # noqa: E402
from benchmarks.generalisation.provenance import provenance_words  # noqa: E402
from benchmarks.generalisation.runner import run  # noqa: E402
from benchmarks.generalisation.scoring import report, score_all, summary  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results" / "generalisation.md"
HIDDEN_RESULTS = ROOT / "benchmarks" / "results" / "generalisation_hidden.md"
HEADER = """# Generalisation benchmark, linear part

Produced by `benchmarks/generalisation.py` (issue 20): random linear structures synthesised
exactly in the frequency domain (numpy only, not the library's simulator), identified by
`fnsi.identification.identify` with its defaults (band of the excitation, order and block
rows `"auto"`), scored blind. A required mode is in the band and carries at least 1 % of
the response power there; it is found when a reported mode is within 0.5 % in frequency and
10 % in damping ratio. Order correct: every required mode found and no spurious mode in the
band. Timings measured on a shared, loaded 2-core machine."""
HIDDEN_HEADER = """# Generalisation benchmark, hidden-effect part

Produced by `benchmarks/generalisation.py --part hidden` (issue 21): the linear part's
random structures and tests (shorter records: 40-120 lines in the band, at most 4096
samples per period, 3 periods) with 0, 1 or 2 hidden nonlinear elements at measured DOFs,
each sized so that the true underlying linear structure misses the noise-free estimation
and validation responses by 3-60 % NRMSE (the smaller of the two set to a drawn target, so
that the effect acts in both records); simulated to periodic steady state by scipy's DOP853 (not the
library's simulator) and sampled through an ideal anti-aliasing filter, as a lab's
acquisition does; validation record: another random-phase realisation. The library
runs the study loop as a user would with its defaults (`Study.create` with only the band,
order `"auto"`; `diagnose`; the top candidate added, with its partner when claimed with
one, when the diagnosis finds one; a second round), every answer recorded before the
truth is read. Kind classes: cubic (hardening or softening), quadratic stiffness,
two-sided clearance (symmetric or asymmetric), one-sided stop (side must match), Coulomb
friction, quadratic damping; a location is the pair of DOFs or a DOF and the ground.
Timings measured on a shared, heavily loaded 2-core machine (two cases at a time)."""

ORACLE_HEADER = """# Generalisation benchmark, hidden-effect part: the loop against the truth

Produced by `benchmarks/generalisation.py --part hidden --phase oracle` after the answers
(`benchmarks/generalisation/oracle.py`): per case with an effect, the true elements added
to the library's linear revision in one study revision (a clearance's gaps as drawn, and
moved into the measured coordinate by the offset that fits with the poles held: the
better validated is kept, so the oracle bounds what the loop could reach). A failure of the loop is
diagnosis-limited when the true elements reach twice the noise floor, and
identification-limited when they do not: then no diagnosis could have reached it."""


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--part", choices=("linear", "hidden"), default="linear",
                        help="linear structures (issue 20) or hidden effects (issue 21)")
    parser.add_argument("--seed", type=int, default=None, help="default 20, hidden 21")
    parser.add_argument("--count", type=int, default=None, help="default 200, hidden 150")
    parser.add_argument("--jobs", type=int, default=2,
                        help="processes generating and answering cases (hidden part)")
    parser.add_argument("--smoke", action="store_true",
                        help="first 30 cases only (hidden: 10); the table goes to the work "
                             "directory")
    parser.add_argument("--noise-free", action="store_true",
                        help="the same cases without measurement noise (checks the "
                             "generator: some order must then be correct on every case)")
    parser.add_argument("--workdir", type=Path, default=None,
                        help="benchmark directory (default: a fresh temporary one)")
    parser.add_argument("--phase", choices=("all", "generate", "run", "score", "oracle"),
                        default="all",
                        help="oracle (hidden part, after the answers): the true elements "
                             "added to the library's linear revision, against the loop")
    parser.add_argument("--results", type=Path, default=None,
                        help=f"Markdown table (default {RESULTS.relative_to(ROOT)} for a full "
                             "run of all phases, else generalisation.md in the work directory)")
    args = parser.parse_args(argv)
    if args.part == "hidden":
        hidden(args)
        return
    seed = 20 if args.seed is None else args.seed
    count = 30 if args.smoke else (args.count or 200)
    root = args.workdir or Path(tempfile.mkdtemp(prefix="generalisation-"))
    print(f"benchmark directory {root}", flush=True)
    if args.phase in ("all", "generate"):
        generate(root, seed, count, noise_free=args.noise_free)
        print(f"generated {count} cases (seed {seed}"
              f"{', noise free' if args.noise_free else ''})", flush=True)
    if args.phase in ("all", "run"):
        run(root, lambda case, a: print(
            f"{case}: {a['status']}, order {a.get('order')}, {len(a.get('modes', []))} modes, "
            f"{a['identify_s']:.2f} s", flush=True))
    if args.phase in ("all", "score"):
        scores = score_all(root, lambda message: print(message, flush=True))
        scratch = args.smoke or args.noise_free or args.phase != "all"
        target = args.results or (root / "generalisation.md" if scratch else RESULTS)
        blas = ", ".join(f"{name}={os.environ.get(name, '(unset)')}"
                         for name in ("OPENBLAS_CORETYPE", "OPENBLAS_NUM_THREADS"))
        target.write_text(report(scores, seed, f"{HEADER}\n\nRun with {blas}. The "
                                 "automatic order can depend on rounding: compare runs made "
                                 "with one BLAS setting, on the same case files."))
        print(f"table written to {target}")
        print(json.dumps(summary(scores)))


def _print_drawn(case: str, truth: dict) -> None:
    """Progress of the hidden part's generation, without what was drawn: whoever runs
    the benchmark answers blind too (the kinds, and the linear error that tells a case
    without an effect, are read in the score phase)."""
    print(f"{case}: {'skipped' if 'skipped' in truth else 'drawn'}", flush=True)


def hidden(args: argparse.Namespace) -> None:
    """The hidden-effect part's phases (module docstring)."""
    seed = 21 if args.seed is None else args.seed
    count = 10 if args.smoke else (args.count or 150)
    root = args.workdir or Path(tempfile.mkdtemp(prefix="generalisation-hidden-"))
    print(f"benchmark directory {root}", flush=True)
    if args.phase in ("all", "generate"):
        start = time.perf_counter()
        drawn = generate_hidden(root, seed, count, noise_free=args.noise_free,
                                jobs=args.jobs, progress=_print_drawn)
        print(f"generated {len(drawn)} of {count} cases (seed {seed}) in "
              f"{time.perf_counter() - start:.0f} s", flush=True)
    if args.phase in ("all", "run"):
        start = time.perf_counter()
        run(root, lambda case, a: print(
            f"{case}: {a['status']}, " + "; ".join(
                f"{'found' if r['found'] else 'nothing'} "
                f"{r['candidates'][0]['effect'] if r['found'] else ''} "
                f"{r['diagnosis_s']:.0f} s" for r in a["rounds"]), flush=True), jobs=args.jobs)
        print(f"answered in {time.perf_counter() - start:.0f} s", flush=True)
    if args.phase in ("all", "score"):
        scores = hidden_scoring.score_hidden(root, lambda message: print(message, flush=True))
        scratch = args.smoke or args.noise_free or args.phase != "all"
        target = args.results or (root / "generalisation_hidden.md" if scratch
                                  else HIDDEN_RESULTS)
        index = read_index(root)
        answers = read_answers(root, index["cases"])
        target.write_text(hidden_scoring.report(scores, seed, HIDDEN_HEADER,
                                                index.get("skipped"),
                                                provenance_words(index, answers)))
        print(f"table written to {target}")
        print(json.dumps(hidden_scoring.summary(scores)))
    if args.phase == "oracle":
        start = time.perf_counter()
        run_oracle(root, lambda case, o: print(
            f"{case}: {o['status']}, linear {o.get('linear_pct')} %, true elements "
            f"{o.get('oracle_pct')} %, floor {o.get('noise_floor_pct')} %", flush=True),
                   jobs=args.jobs)
        table, totals = oracle_report(root)
        target = args.results or root / "oracle.md"
        target.write_text(f"{ORACLE_HEADER}\n\nSeed {seed}, {time.perf_counter() - start:.0f} s."
                          f"\n\n{table}")
        print(f"table written to {target}")
        print(json.dumps(totals))


if __name__ == "__main__":
    try:
        main()
    except ValueError as error:  # a phase out of order or a used directory: say what to do
        sys.exit(f"error: {error}")
