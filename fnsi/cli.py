"""The ``fnsi`` command line: simulate, inspect, identify and run modelling studies
without the service.

It calls the same library functions as the service's workers and writes the same
artefacts (``result.json``, ``model.npz`` and the PNG figures) into a folder.

Examples
--------
::

    fnsi simulate single --periods 4 --samples-per-period 5000 -o single.npz
    fnsi info single.npz
    fnsi identify single.npz --outputs NC2w_Z,NC2b_Z,W_Z --band 5 50 --block-rows 100 \\
        --element '{"kind": "clearance", "dof": "NC2w_Z", "ref": "NC2b_Z", "gap": 1.5}' \\
        -o single-result
    fnsi study create single.npz single-validation.npz --outputs NC2w_Z,NC2b_Z,W_Z \\
        --band 5 50 --block-rows 100 -o nc2-study
    fnsi study diagnose nc2-study            # ranked candidates, with --add JSON for each
    fnsi study revise nc2-study --add '{"kind": "clearance", "dof": "NC2w_Z", ...}'
    fnsi study show nc2-study
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from fnsi.html_report import REPORT_NAME


def _progress(fraction: float, message: str) -> None:
    print(f"\r[{fraction:6.1%}] {message:<60.60}", end="", file=sys.stderr, flush=True)


def _channels(text: str | None) -> tuple[str, ...] | None:
    return tuple(name.strip() for name in text.split(",") if name.strip()) if text else None


def _read(path: str, args: argparse.Namespace):
    """The measurement in ``path``, any format, read as the service reads uploads."""
    from fnsi.formats import ReadOptions, format_of, read_measurement

    options = ReadOptions(fs=args.fs, inputs=_channels(args.inputs),
                          outputs=_channels(getattr(args, "outputs", None)),
                          periods=args.periods, quantity=args.quantity,
                          units=_units(args.units), group=args.group)
    measurement, _ = read_measurement(Path(path), format_of(path, args.format), options)
    return measurement


def _units(text: str | None) -> dict[str, str] | None:
    """``name=unit,name=unit`` as a mapping."""
    if not text:
        return None
    pairs = [item.split("=", 1) for item in text.split(",") if item.strip()]
    if any(len(pair) != 2 for pair in pairs):
        raise ValueError(f"--units takes name=unit pairs separated by commas, e.g. "
                         f"force=N,x1=mm; got {text!r}")
    return {name.strip(): unit.strip() for name, unit in pairs}


def _elements(args: argparse.Namespace) -> tuple:
    from fnsi.nonlinear import NonlinearElement

    specs = [json.loads(text) for text in args.element]
    if args.elements:
        loaded = json.loads(Path(args.elements).read_text())
        specs.extend(loaded if isinstance(loaded, list) else [loaded])
    return tuple(NonlinearElement.from_json(spec) for spec in specs)


def _cmd_simulate(args: argparse.Namespace) -> int:
    from fnsi.smallsat import simulate_preset

    measurement, truth = simulate_preset(
        args.preset,
        periods=args.periods,
        samples_per_period=args.samples_per_period,
        seed=args.seed,
        noise_percent=args.noise_percent,
        progress=_progress,
    )
    print(file=sys.stderr)
    output = Path(args.output)
    measurement.to_npz(output)
    truth_path = output.with_suffix(".truth.json")
    truth_path.write_text(json.dumps(truth.to_json(), indent=2))
    print(f"wrote {output} and {truth_path}")
    return 0


def _cmd_info(args: argparse.Namespace) -> int:
    from fnsi.summary import summarize

    m = _read(args.dataset, args)
    # the service's dataset summary: every channel with its unit, RMS and SNR [dB]
    summary = summarize(m, "declared")
    del summary["periods_source"]     # the reader does not say whether it detected them
    print(json.dumps(summary | {"input_units": list(m.input_units),
                                "output_units": list(m.output_units)}, indent=2))
    return 0


def _int_or_auto(text: str) -> int | str:
    return text if text == "auto" else int(text)


def _identification_settings(args: argparse.Namespace, measurement):
    """IdentificationSettings from the options of :func:`_add_identification_options`;
    the band defaults to the lines the input of ``measurement`` excites."""
    from fnsi.distortion import excited_band
    from fnsi.identification import IdentificationSettings

    band = (excited_band(measurement, args.discard_periods) if args.band is None
            else (args.band[0], args.band[1]))
    return IdentificationSettings(
        inputs=_channels(args.inputs),
        outputs=_channels(args.outputs),
        band=band,
        block_rows=_int_or_auto(args.block_rows),
        order=_int_or_auto(args.order),
        max_order=args.max_order,
        line_set=args.line_set,
        discard_periods=args.discard_periods,
        elements=_elements(args),
        weighting=args.weighting,
        frequency_warping=args.frequency_warping,
        driving_points=tuple(_pair(text) for text in args.driving_point),
        refine=args.refine, uncertainty=not args.no_uncertainty,
        remove_offsets=args.remove_offsets,
    )


def _pair(text: str) -> tuple[str, str]:
    names = _channels(text) or ()
    if len(names) != 2:
        raise ValueError(f"expected two comma-separated channel names, got {text!r}")
    return names[0], names[1]


def _cmd_identify(args: argparse.Namespace) -> int:
    from fnsi.identification import identify
    from fnsi.report import identification_report

    measurement = _read(args.dataset, args)
    settings = _identification_settings(args, measurement)
    result = identify(measurement, settings, progress=_progress)
    report = identification_report(result, settings, measurement, progress=_progress)
    print(file=sys.stderr)
    _write_files(Path(args.output), report.artefacts)
    folder = Path(args.output)
    for warning in report.document["warnings"]:
        print(f"warning: {warning}")
    print(f"order {result.order}; artefacts in {folder}/")
    for mode in report.document["modes"]:
        print(f"  {mode['frequency_hz']:9.4f}{_std(mode['frequency_hz_std'], 1, '.2g')} Hz  "
              f"damping {100 * mode['damping_ratio']:6.3f}"
              f"{_std(mode['damping_ratio_std'], 100, '.2g')} %")
    for c in report.document["coefficients"]:
        quality = (f"mean Re {c['mean_real']:.6g}{_std(c['mean_real_std'], 1, '.2g')} "
                   f"{c['unit']}, log10(Re/Im) {c['log10_real_imag']:.2f}"
                   if c.get("mean_real") is not None else c["reason"])
        print(f"  {c['name']}: {quality}")
    note = (report.document.get("uncertainty") or {}).get("note")
    if note:
        print(f"  {note}")
    for separation in result.separability:
        if separation.concern:
            print(f"  warning: {separation.concern}")
    if result.refinement is not None:
        print(result.refinement.summary)
    print(result.offsets.summary("estimation") + ("; removed before the estimation"
                                                  if settings.remove_offsets else ""))
    return 0


def _std(value: float | None, scale: float, spec: str) -> str:
    """" +- std" of a value (times ``scale``), or nothing when there is no error bar."""
    return "" if value is None else f" \u00b1 {scale * value:{spec}}"


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``fnsi`` command (exposed for documentation and tests)."""
    parser = argparse.ArgumentParser(
        prog="fnsi",
        description="Frequency-domain nonlinear subspace identification of structures.",
    )
    commands = parser.add_subparsers(dest="command", required=True)

    simulate = commands.add_parser(
        "simulate", help="simulate a SmallSat preset and write a canonical NPZ dataset"
    )
    simulate.add_argument("preset", choices=["single", "multi"],
                          help="single: one clearance NC2w_Z-NC2b_Z, 100 N; multi: eight "
                          "clearances, 200 N (the paper's Section IV)")
    simulate.add_argument("-o", "--output", required=True, help="NPZ file to write")
    simulate.add_argument("--periods", type=int, default=8,
                          help="periods of the multisine, the first ones transient (default "
                          "8, the paper's)")
    simulate.add_argument("--samples-per-period", type=int, default=30_000,
                          help="samples per period at 2.5 kHz (default 30,000, the paper's "
                          "12 s: 8 x 30,000 samples take about a minute; 2,500 gives a 1 s "
                          "period for a quick look)")
    simulate.add_argument("--seed", type=int, default=0,
                          help="random phases and noise (default 0)")
    simulate.add_argument("--noise-percent", type=float, default=0.5,
                          help="output noise RMS in %% of the reference channel's RMS")
    simulate.set_defaults(run=_cmd_simulate)

    info = commands.add_parser("info", help="summarise a dataset (npz, csv, mat, h5, uff)")
    info.add_argument("dataset", help="dataset file (npz, csv, mat, h5, uff)")
    info.add_argument("--inputs", help="comma-separated input channels (a CSV needs them)")
    info.add_argument("--outputs", help="comma-separated output channels (default: all; a "
                      "UFF file mixing quantities needs those of one)")
    _add_read_options(info)
    info.set_defaults(run=_cmd_info)

    ident = commands.add_parser(
        "identify", help="identify a dataset with FNSI and write result.json, model.npz, PNGs "
        "and report.html"
    )
    ident.add_argument("dataset", help="dataset file (npz, csv, mat, h5, uff)")
    ident.add_argument("-o", "--output", required=True, help="folder for the artefacts")
    _add_identification_options(ident)
    _add_read_options(ident)
    ident.set_defaults(run=_cmd_identify)

    analyse = commands.add_parser(
        "analyse", help="nonlinear distortion levels before any model (BLA, noise, odd and "
        "even distortions): prints a verdict, writes analysis.json, distortion.png and "
        "report.html")
    analyse.add_argument("dataset", help="dataset file (npz, csv, mat, h5, uff)")
    analyse.add_argument("-o", "--output", help="folder for analysis.json, distortion.png and "
                         "report.html")
    analyse.add_argument("--inputs", help="comma-separated input channels (a CSV needs them)")
    analyse.add_argument("--outputs", help="comma-separated output channels (default all)")
    analyse.add_argument("--discard-periods", type=int, default=1,
                         help="leading transient periods left out (default 1)")
    _add_read_options(analyse)
    analyse.set_defaults(run=_cmd_analyse)

    _add_study_commands(commands)
    return parser


def _cmd_analyse(args: argparse.Namespace) -> int:
    from fnsi.distortion import analyse_distortion
    from fnsi.report import analysis_artefacts

    measurement = _read(args.dataset, args)
    if args.outputs:
        measurement = measurement.select(outputs=_channels(args.outputs))
    analysis = analyse_distortion(measurement, discard_periods=args.discard_periods)
    print(f"{'output':<14} {'excited':>9} {'odd':>9} {'even':>9} {'above':>9}  "
          "[dB over the noise; * above it]")
    for channel in analysis.channels:
        cells = [_group_cell(g) for g in (channel.excited, channel.odd, channel.even,
                                          channel.above_band)]
        print(f"{channel.name:<14} " + " ".join(f"{c:>9}" for c in cells))
    print(analysis.verdict)
    if args.output:
        _write_files(Path(args.output), analysis_artefacts(analysis))
    return 0


def _write_files(folder: Path, files: dict[str, bytes]) -> None:
    """Write ``files`` (name to content) into ``folder`` and list them."""
    folder.mkdir(parents=True, exist_ok=True)
    for name, content in files.items():
        (folder / name).write_bytes(content)
    print(f"wrote in {folder}/: {', '.join(files)}")


def _group_cell(group) -> str:
    if group.lines == 0:
        return "-"
    return f"{group.level_db:.1f}{'*' if group.above_noise else ''}"


def _add_read_options(parser: argparse.ArgumentParser) -> None:
    """What completes or overrides a dataset file (fnsi.formats.ReadOptions)."""
    parser.add_argument("--format", help="npz, csv, mat, h5 or uff (default: from the "
                        "extension)")
    parser.add_argument("--fs", type=float, help="sampling rate [Hz] (a CSV needs it)")
    parser.add_argument("--periods", type=int,
                        help="excitation periods per record (default: the file's, else "
                        "detected)")
    parser.add_argument("--quantity", help="displacement, velocity or acceleration: what the "
                        "outputs measure (default: the file's)")
    parser.add_argument("--units", help="channel units overriding the file's, e.g. "
                        "force=N,x1=mm (default: the file's; labels say 'input unit' and "
                        "'output unit' where none is given)")
    parser.add_argument("--group", help="HDF5 / MATLAB v7.3: the group holding u and y "
                        "(default: the root, or the one group holding them)")


def _add_identification_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--inputs", help="comma-separated input names (default: all; the "
                        "input columns of a CSV)")
    parser.add_argument("--outputs", help="comma-separated output names (default: all)")
    parser.add_argument("--band", nargs=2, type=float, default=None,
                        metavar=("LOW_HZ", "HIGH_HZ"),
                        help="analysis band (default: the lowest to the highest frequency "
                             "the input excites)")
    parser.add_argument("--block-rows", default="auto",
                        help="the paper's i, or 'auto' (default: twice the rows order "
                        "max-order needs, within what the harmonic lines allow)")
    parser.add_argument("--order", default="auto",
                        help="model order n, or 'auto' (default: from the stabilisation "
                        "diagram)")
    parser.add_argument("--max-order", type=int, default=60,
                        help="highest order of the stabilisation diagram (default 60)")
    parser.add_argument("--line-set", choices=["all", "excited"], default="all",
                        help="lines of the band used: all, or the ones the input excites "
                        "(default all)")
    parser.add_argument("--discard-periods", type=int, default=1,
                        help="leading transient periods left out (default 1)")
    parser.add_argument("--weighting", action=argparse.BooleanOptionalAction, default="auto",
                        help="weight by the noise covariance estimated between periods "
                        "(default: on for velocity and acceleration records whose order "
                        "is chosen by simulation, as in studies; off otherwise)")
    parser.add_argument("--frequency-warping", action="store_true",
                        help="build the data matrices in a warped frequency variable "
                        "(changes the model class; off by default)")
    parser.add_argument("--refine", action="store_true",
                        help="refine the model by minimising its simulation error (slower; "
                        "the model then reproduces the measurement much more closely)")
    parser.add_argument("--no-uncertainty", action="store_true",
                        help="skip the standard deviations (+- in the modal table; they "
                        "add 15-50 %% to the identification's time)")
    parser.add_argument("--element", action="append", default=[],
                        help="a nonlinear element as JSON (repeatable)")
    parser.add_argument("--elements", help="JSON file with a list of nonlinear elements")
    parser.add_argument("--driving-point", action="append", default=[], metavar="INPUT,OUTPUT",
                        help="output measured at the point and direction of an input "
                        "(repeatable; default: found by name)")
    parser.add_argument("--remove-offsets", action="store_true",
                        help="remove each channel's mean (a sensor offset) before the "
                        "estimation, so that the elements see zero-mean displacement; for "
                        "displacement sensors not zeroed at the equilibrium")


# -- fnsi study: modelling studies kept in a folder (fnsi.study.Study.save / load) ---------
def _save_study(study, folder: Path, figures: dict[str, bytes]) -> None:
    """Save ``study`` to ``folder`` with its new figures, replacing the folder only once
    the new one is complete (a failure leaves the previous study intact); figures and
    diagnoses of earlier revisions are kept. The report (``report.html``) is redrawn."""
    import shutil

    folder = folder.resolve()
    partial = folder.with_name(folder.name + ".partial")
    previous = folder.with_name(folder.name + ".previous")
    for stale in (partial, previous):
        shutil.rmtree(stale, ignore_errors=True)
    study.save(partial)
    if folder.is_dir():
        for old in folder.iterdir():
            if not (partial / old.name).exists():
                old.replace(partial / old.name)
        folder.rename(previous)
    partial.rename(folder)
    shutil.rmtree(previous, ignore_errors=True)
    _write_files(folder, figures)
    _write_files(folder, {REPORT_NAME: _study_report(folder)})


def _study_report(folder: Path) -> bytes:
    """The one-page report of the study saved in ``folder``, with its figures and every
    diagnosis written there (``diagnosis-<n>.json`` and ``diagnosis-<n>-*.png``)."""
    from fnsi.html_report import DiagnosisPart, study_page

    figures = {p.name: p.read_bytes() for p in sorted(folder.glob("*.png"))
               if not p.name.startswith("diagnosis-")}
    diagnoses = []
    for path in sorted(folder.glob("diagnosis-*.json"), key=lambda p: int(p.stem.split("-")[1])):
        prefix = f"{path.stem}-"
        diagnoses.append(DiagnosisPart(json.loads(path.read_text()), {
            p.name.removeprefix(prefix): p.read_bytes() for p in folder.glob(f"{prefix}*.png")}))
    return study_page(json.loads((folder / "study.json").read_text()), figures, diagnoses)


def _cmd_study_create(args: argparse.Namespace) -> int:
    from fnsi.study import Study
    from fnsi.study_plots import study_figures

    folder = Path(args.output)
    if (folder / "study.json").exists():
        raise ValueError(f"{folder} already holds a study; choose another folder or add a "
                         f"revision with 'fnsi study revise {folder}'")
    estimation = _read(args.estimation, args)
    study = Study.create(estimation, _read(args.validation, args),
                         _identification_settings(args, estimation),
                         connections=[_pair(text) for text in args.connection],
                         name=args.name, note=args.note, progress=_progress)
    print(file=sys.stderr)
    _save_study(study, folder, study_figures(study))
    print(study.history_table())
    print(f"study saved in {folder}/")
    return 0


def _removal(text: str) -> int | dict:
    """An element to remove: its index in the base revision, or its JSON."""
    return int(text) if text.strip().isdigit() else json.loads(text)


def _cmd_study_revise(args: argparse.Namespace) -> int:
    from fnsi.study import Study
    from fnsi.study_plots import study_figures

    study = Study.load(args.study)
    revision = study.add_revision(
        add=[json.loads(text) for text in args.add], remove=[_removal(t) for t in args.remove],
        order=None if args.order is None else _int_or_auto(args.order), note=args.note,
        base=-1 if args.base is None else args.base, progress=_progress)
    print(file=sys.stderr)
    _save_study(study, Path(args.study), study_figures(study, revision.number))
    print(study.history_table())
    for separation in revision.separability:
        if separation["concern"]:
            print(f"warning: {separation['concern']}")
    return 0


def _cmd_study_diagnose(args: argparse.Namespace) -> int:
    from fnsi.diagnosis import DiagnosisSettings
    from fnsi.study import Study
    from fnsi.study_plots import diagnosis_figures, study_figures

    folder = Path(args.study)
    study = Study.load(folder)
    settings = DiagnosisSettings(top_locations=args.top_locations,
                                 validated_candidates=args.validated_candidates,
                                 curve_locations=args.curve_locations,
                                 include_missing_mode=not args.no_missing_mode)
    number = len(study.revisions) - 1 if args.revision is None else args.revision
    diagnosis = study.diagnose(number, settings, progress=_progress)
    print(file=sys.stderr)
    prefix = f"diagnosis-{diagnosis.revision}"
    files = {f"{prefix}.json": json.dumps(diagnosis.to_json(), indent=1).encode()}
    files |= {f"{prefix}-{name}": png for name, png in diagnosis_figures(diagnosis).items()}
    print(diagnosis.summary)
    for rank, candidate in enumerate(diagnosis.candidates, start=1):
        if candidate.failure is not None:
            print(f"{rank}. {candidate.effect.value}: failed: {candidate.failure}")
        else:
            print(f"{rank}. {candidate.effect.value}: validation NRMSE "
                  f"{candidate.validation_nrmse_percent:.3g} % "
                  f"(x{candidate.error_reduction_factor:.3g} better)"
                  f"{'' if candidate.beats_noise_floor else ', not claimed'}"
                  f"{'' if candidate.concern is None else ', physically implausible'}")
        print(f"   {candidate.explanation}")
        for element in candidate.elements:
            print(f"   --add '{json.dumps(element.to_json())}'")
    for note in diagnosis.notes:
        print(f"note: {note}")
    _write_files(folder, files)
    _write_files(folder, {REPORT_NAME: _study_report(folder)})
    best = diagnosis.candidates[0] if diagnosis.candidates else None
    if args.apply and best is not None and best.elements and diagnosis.found:
        revision = study.add_revision(add=best.elements,
                                      base=diagnosis.revision, progress=_progress)
        print(file=sys.stderr)
        _save_study(study, folder, study_figures(study, revision.number))
        print(study.history_table())
    return 0


def _cmd_study_show(args: argparse.Namespace) -> int:
    from fnsi.study import Study

    study = Study.load(args.study)
    if args.json:
        print(json.dumps({"name": study.name, "history": study.history(),
                          "revisions": [r.to_json() for r in study.revisions]}, indent=1))
    else:
        print(study.history_table())
    return 0


def _add_study_commands(commands) -> None:
    study = commands.add_parser(
        "study", help="modelling study: revisions judged on validation data, diagnoses")
    actions = study.add_subparsers(dest="action", required=True)

    create = actions.add_parser(
        "create", help="identify a starting model (revision 0) and validate it")
    create.add_argument("estimation", help="dataset file to identify on (any format)")
    create.add_argument("validation", help="dataset file of the same set-up")
    create.add_argument("-o", "--output", required=True, help="folder to keep the study in")
    _add_identification_options(create)
    _add_read_options(create)
    create.add_argument("--connection", action="append", default=[], metavar="OUT_A,OUT_B",
                        help="two outputs a physical element could join (repeatable)")
    create.add_argument("--name", default="", help="free label")
    create.add_argument("--note", default="starting model", help="what revision 0 is")
    create.set_defaults(run=_cmd_study_create)

    revise = actions.add_parser("revise", help="add a revision: add or remove elements, "
                                "change the order")
    revise.add_argument("study", help="study folder")
    revise.add_argument("--add", action="append", default=[], metavar="JSON",
                        help="nonlinear element to add, as JSON (repeatable)")
    revise.add_argument("--remove", action="append", default=[], metavar="INDEX|JSON",
                        help="element of the base revision to remove (repeatable)")
    revise.add_argument("--order", help="new model order n, or 'auto' (default: keep)")
    revise.add_argument("--note", help="what changed (default: generated)")
    revise.add_argument("--base", type=int, help="revision to start from (default: latest)")
    revise.set_defaults(run=_cmd_study_revise)

    diagnose = actions.add_parser("diagnose", help="rank candidate missing effects")
    diagnose.add_argument("study", help="study folder")
    diagnose.add_argument("--revision", type=int, help="revision to diagnose (default: latest)")
    diagnose.add_argument("--top-locations", type=int, default=3,
                          help="locations screened further per kind of effect (default 3)")
    diagnose.add_argument("--validated-candidates", type=int, default=4,
                          help="most candidates identified and simulated on the validation "
                          "data, the two best first, the others only when neither reaches "
                          "twice the noise floor (default 4)")
    diagnose.add_argument("--curve-locations", type=int, default=1,
                          help="locations whose spline stiffness curve is drawn (default 1)")
    diagnose.add_argument("--no-missing-mode", action="store_true",
                          help="do not try one more linear mode")
    diagnose.add_argument("--apply", action="store_true",
                          help="add the best candidate as a new revision if it passes the "
                          "claim rule")
    diagnose.set_defaults(run=_cmd_study_diagnose)

    show = actions.add_parser("show", help="print the error history")
    show.add_argument("study", help="study folder")
    show.add_argument("--json", action="store_true", help="revisions and errors as JSON")
    show.set_defaults(run=_cmd_study_show)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``fnsi`` console script."""
    args = build_parser().parse_args(argv)
    try:
        return int(args.run(args))
    except (ValueError, FileNotFoundError) as exc:
        print(f"fnsi: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
