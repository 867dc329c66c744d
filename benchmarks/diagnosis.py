"""Benchmark: diagnosis of the SmallSat ``single`` study with all 39 outputs (issue 7).

Estimation and validation data are two realisations of the paper's single-nonlinearity
test (100 N RMS at NC2w_Z, only the NC2-Z stop in contact). Revision 0 is linear; the
diagnosis should name the clearance between NC2w_Z and NC2b_Z, and adding it should
bring the validation NRMSE down to the noise floor.

Prints the stage timings, the ranked candidates and the error history; the last line is
one JSON object::

    {"diagnosis_s": ..., "top_effect": ..., "top_dof": ..., "top_ref": ...,
     "nrmse_before_pct": ..., "nrmse_after_pct": ..., "noise_floor_pct": ...,
     "stop_rank": ..., "true_stop_nrmse_pct": ...}

``stop_rank`` is the screening rank (1: best) of the NC2w_Z-NC2b_Z location and
``true_stop_nrmse_pct`` the validation NRMSE of revision 0 with the true stop added
(clearance and gap from the simulation's truth): what a correct diagnosis reaches with
these identification settings. An NRMSE is null when its model could not be simulated
(unstable or diverging).

Run: ``.venv/bin/python benchmarks/diagnosis.py [--periods 8 --samples-per-period 30000]``;
``--refine`` refines every revision and validated candidate by its simulation error
(:mod:`fnsi.refinement`), ``--outputs NC2w_Z,NC2b_Z,W_Z`` studies the single-3 channels;
``--noise-percent 0 --band-high 200 --order 36`` shows what the true stop reaches without
noise when the model also sees the lines above the excitation.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace

from fnsi.diagnosis import DiagnosisSettings, Location
from fnsi.errors import json_float
from fnsi.identification import IdentificationSettings
from fnsi.smallsat import simulate_preset
from fnsi.study import Study


def _progress(fraction: float, message: str) -> None:
    print(f"\r  [{fraction:6.1%}] {message:<60.60}", end="", file=sys.stderr, flush=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--periods", type=int, default=8)
    parser.add_argument("--samples-per-period", type=int, default=30_000)
    parser.add_argument("--discard-periods", type=int, default=2)
    parser.add_argument("--block-rows", type=int, default=20,
                        help="FNSI i of every revision (the paper's 50 is slower)")
    parser.add_argument("--order", type=int, default=18, help="starting linear order")
    parser.add_argument("--line-set", choices=["all", "excited"], default="excited",
                        help="FNSI lines: the excited harmonics averaged over the periods "
                             "(6 x fewer lines than 'all', same information on the FRF)")
    parser.add_argument("--band-high", type=float, default=50.0,
                        help="upper edge of the identification band [Hz]; above the 50 Hz "
                             "excitation only the nonlinear forces excite the structure")
    parser.add_argument("--noise-percent", type=float, default=0.5,
                        help="output noise in %% of the bracket tip's RMS (0: noise-free, "
                             "to separate model error from noise)")
    parser.add_argument("--validated", type=int, default=3,
                        help="candidates identified and simulated on validation data")
    parser.add_argument("--outputs", default=None,
                        help="comma-separated outputs of the study (default: all 39)")
    parser.add_argument("--refine", action="store_true",
                        help="refine every revision and candidate by its simulation error")
    args = parser.parse_args()

    start = time.perf_counter()
    record = {"periods": args.periods, "samples_per_period": args.samples_per_period,
              "noise_percent": args.noise_percent}
    outputs = None if args.outputs is None else tuple(args.outputs.split(","))
    estimation, truth = simulate_preset("single", seed=1, outputs=outputs, **record)
    validation, _ = simulate_preset("single", seed=2, outputs=outputs, **record)
    simulation_s = time.perf_counter() - start
    print(f"simulated 2 x {args.periods} x {args.samples_per_period} samples, "
          f"{estimation.n_outputs} outputs in {simulation_s:.1f} s; exceedances "
          f"{ {k: v for k, v in truth.exceedances.items() if v} }")

    settings = IdentificationSettings(
        band=(5.0, args.band_high), block_rows=args.block_rows, order=args.order,
        max_order=max(args.order, 30), discard_periods=args.discard_periods,
        line_set=args.line_set, refine=args.refine,
        driving_points=((estimation.input_names[0], "NC2w_Z"),))
    start = time.perf_counter()
    study = Study.create(estimation, validation, settings, name="smallsat-single")
    print(f"revision 0 (linear, order {args.order}) in {time.perf_counter() - start:.1f} s")

    start = time.perf_counter()
    diagnosis = study.diagnose(settings=DiagnosisSettings(validated_candidates=args.validated),
                               progress=_progress)
    diagnosis_s = time.perf_counter() - start
    print(file=sys.stderr)
    print(f"diagnosis in {diagnosis_s:.1f} s: "
          + ", ".join(f"{k} {v:.2f}" for k, v in diagnosis.timings.items()))
    print(f"{len(diagnosis.locations)} locations screened; best:")
    for score in diagnosis.locations[:5]:
        print(f"  {score.location.label:<18} explains {100 * score.reduction:5.1f} %")
    print("candidates (validated):")
    for c in diagnosis.candidates:
        where = c.location.label if c.location else f"order {c.order}"
        print(f"  {c.effect.value:<20} {where:<18} {c.validation_nrmse_percent:9.3g} %")
    print(diagnosis.summary)

    stop = next(e for e in truth.elements if (e.dof, e.ref) == ("NC2w_Z", "NC2b_Z"))
    stop_rank = 1 + [s.location for s in diagnosis.locations].index(
        Location(stop.dof, stop.ref))
    true_stop = study.evaluate([replace(stop, coefficients=None)], args.order)
    print(f"{stop.name} ranks {stop_rank} of {len(diagnosis.locations)} in the screening; "
          f"with the true stop the validation NRMSE is {true_stop.nrmse_percent:.3g} %")

    top = diagnosis.candidates[0]
    if top.element is not None and top.beats_noise_floor:
        study.add_revision(add=[top.element], note=top.effect.value)
    elif top.beats_noise_floor:
        study.add_revision(order=top.order, note="one more mode")
    print(study.history_table())
    last = study.revisions[-1]
    print(json.dumps({
        "diagnosis_s": round(diagnosis_s, 2),
        "top_effect": top.effect.value,
        "top_dof": None if top.location is None else top.location.dof,
        "top_ref": None if top.location is None else top.location.ref,
        "nrmse_before_pct": json_float(diagnosis.nrmse_before_percent),
        "nrmse_after_pct": json_float(last.nrmse_percent),
        "noise_floor_pct": json_float(study.noise_floor_percent),
        "stop_rank": stop_rank,
        "true_stop_nrmse_pct": json_float(true_stop.nrmse_percent),
    }, allow_nan=False))
    return 0


if __name__ == "__main__":
    sys.exit(main())
