"""Generalisation benchmark, linear part (issue 20): random structures identified blind.

Three phases (:mod:`benchmarks.generalisation`):

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
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # this checkout's fnsi and benchmarks, not an installed copy

from benchmarks.generalisation.cases import generate  # noqa: E402
from benchmarks.generalisation.runner import run  # noqa: E402
from benchmarks.generalisation.scoring import report, score_all, summary  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results" / "generalisation.md"
HEADER = """# Generalisation benchmark, linear part

Produced by `benchmarks/generalisation.py` (issue 20): random linear structures synthesised
exactly in the frequency domain (numpy only, not the library's simulator), identified by
`fnsi.identification.identify` with its defaults (band of the excitation, order and block
rows `"auto"`), scored blind. A required mode is in the band and carries at least 1 % of
the response power there; it is found when a reported mode is within 0.5 % in frequency and
10 % in damping ratio. Order correct: every required mode found and no spurious mode in the
band. Timings measured on a shared, loaded 2-core machine."""


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=20)
    parser.add_argument("--count", type=int, default=200)
    parser.add_argument("--smoke", action="store_true",
                        help="first 30 cases only; the table goes to the work directory")
    parser.add_argument("--noise-free", action="store_true",
                        help="the same cases without measurement noise (checks the "
                             "generator: some order must then be correct on every case)")
    parser.add_argument("--workdir", type=Path, default=None,
                        help="benchmark directory (default: a fresh temporary one)")
    parser.add_argument("--phase", choices=("all", "generate", "run", "score"), default="all")
    parser.add_argument("--results", type=Path, default=None,
                        help=f"Markdown table (default {RESULTS.relative_to(ROOT)} for a full "
                             "run of all phases, else generalisation.md in the work directory)")
    args = parser.parse_args(argv)
    count = 30 if args.smoke else args.count
    root = args.workdir or Path(tempfile.mkdtemp(prefix="generalisation-"))
    print(f"benchmark directory {root}", flush=True)
    if args.phase in ("all", "generate"):
        generate(root, args.seed, count, noise_free=args.noise_free)
        print(f"generated {count} cases (seed {args.seed}"
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
        target.write_text(report(scores, args.seed, f"{HEADER}\n\nRun with {blas}. The "
                                 "automatic order can depend on rounding: compare runs made "
                                 "with one BLAS setting, on the same case files."))
        print(f"table written to {target}")
        print(json.dumps(summary(scores)))


if __name__ == "__main__":
    try:
        main()
    except ValueError as error:  # a phase out of order or a used directory: say what to do
        sys.exit(f"error: {error}")
