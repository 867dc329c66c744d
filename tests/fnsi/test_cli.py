"""The ``fnsi`` command line, run in-process on NPZ files in a temporary folder.

The study commands are driven as a test engineer would: create a study from an
estimation and a validation record of a structure with a hidden clearance (the 5-DOF
chain of :mod:`tests.fnsi.test_diagnosis`), diagnose it, add the element the diagnosis
prints, and show the error history.
"""

from __future__ import annotations

import json
import re

import h5py
import numpy as np
import pytest

from fnsi.cli import main
from fnsi.measurement import Measurement
from fnsi.nonlinear import NonlinearElement
from tests.fnsi.test_diagnosis import REDUCTION, chain, measure
from tests.service import formats

PNG = b"\x89PNG\r\n\x1a\n"
HIDDEN = NonlinearElement("clearance", "x4", "x5", gap_negative=0.002, gap_positive=0.001,
                          coefficients=(1e4,))
# The identification options of tests.fnsi.test_diagnosis.SETTINGS, as command-line words.
IDENTIFICATION = ["--band", "5", "60", "--block-rows", "15", "--order", "10",
                  "--max-order", "20", "--driving-point", "F_x1,x1"]
EFFORT = ["--top-locations", "2", "--validated-candidates", "2", "--no-missing-mode"]


@pytest.fixture(scope="module")
def records(tmp_path_factory):
    """Estimation and validation NPZ files of the chain with the hidden clearance."""
    folder = tmp_path_factory.mktemp("records")
    model = chain(HIDDEN)
    paths = folder / "estimation.npz", folder / "validation.npz"
    for seed, path in zip((1, 2), paths, strict=True):
        measure(model, seed).to_npz(path)
    return paths


def run(capsys, *words: str) -> tuple[int, str, str]:
    code = main([str(w) for w in words])
    out, err = capsys.readouterr()
    return code, out, err


def test_info_prints_the_channels(records, capsys):
    code, out, _ = run(capsys, "info", records[0])
    assert code == 0
    summary = json.loads(out)
    assert summary["outputs"] == ["x1", "x2", "x3", "x4", "x5"]
    # each channel's RMS and SNR (0.5 % output noise, so some 46 dB: 30-70 dB)
    outputs = [c for c in summary["channels"] if c["role"] == "output"]
    assert [c["name"] for c in outputs] == summary["outputs"]
    assert all(c["rms"] > 0 and 30 < c["snr_db"] < 70 for c in outputs)


def test_identify_refined_writes_the_refined_model(records, tmp_path, capsys):
    element = json.dumps({"kind": "clearance", "dof": "x4", "ref": "x5",
                          "gap_negative": 0.002, "gap_positive": 0.001})
    code, out, err = run(capsys, "identify", records[0], *IDENTIFICATION, "--element", element,
                         "--refine", "-o", tmp_path / "refined")
    assert code == 0, err
    said = re.search(r"refined in \d+ steps .*: simulation error ([0-9.]+) % -> ([0-9.]+) %",
                     out)
    assert said and float(said.group(2)) < float(said.group(1)), out
    result = json.loads((tmp_path / "refined" / "result.json").read_text())
    assert result["refinement"]["final_percent"] == pytest.approx(float(said.group(2)),
                                                                  rel=1e-2)
    assert (tmp_path / "refined" / "model.npz").exists()


def test_identify_warns_of_elements_the_data_cannot_separate(records, tmp_path, capsys):
    """The known clearance and a spline at the same connection share their force."""
    stop = json.dumps({"kind": "clearance", "dof": "x4", "ref": "x5",
                       "gap_negative": 0.002, "gap_positive": 0.001})
    spline = json.dumps({"kind": "spline", "dof": "x4", "ref": "x5", "intervals": 9})
    code, out, err = run(capsys, "identify", records[0], *IDENTIFICATION, "--element", stop,
                         "--element", spline, "-o", tmp_path / "both")
    assert code == 0, err
    warnings = [line for line in out.splitlines() if line.strip().startswith("warning:")]
    assert len(warnings) == 2 and "spline x4-x5" in warnings[0], out
    result = json.loads((tmp_path / "both" / "result.json").read_text())
    assert [s["confounded"] for s in result["separability"]] == [True, True]
    assert (tmp_path / "both" / "stiffness.png").read_bytes().startswith(PNG)


def test_identify_says_once_how_to_give_a_missing_driving_point(records, tmp_path, capsys):
    renamed = tmp_path / "shaker.npz"
    data = Measurement.from_npz(records[0])
    Measurement(data.u, data.y, data.fs, ("shaker",), data.output_names, data.periods,
                data.quantity).to_npz(renamed)
    stop = json.dumps({"kind": "clearance", "dof": "x4", "ref": "x5",
                       "gap_negative": 0.002, "gap_positive": 0.001})
    code, out, err = run(capsys, "identify", renamed, *IDENTIFICATION[:-2], "--element", stop,
                         "--no-uncertainty", "-o", tmp_path / "out")
    assert code == 0, err
    warnings = [line for line in out.splitlines() if line.startswith("warning:")]
    assert len(warnings) == 1 and "input 'shaker' names no output" in warnings[0], out
    assert "--driving-point INPUT,OUTPUT" in warnings[0]
    result = json.loads((tmp_path / "out" / "result.json").read_text())
    assert result["warnings"] == [warnings[0].removeprefix("warning: ")]


def test_study_create_diagnose_revise_show(records, tmp_path, capsys):
    folder = tmp_path / "study"
    code, out, err = run(capsys, "study", "create", *records, "-o", folder, *IDENTIFICATION,
                         "--name", "chain")
    assert code == 0, err
    assert "starting model" in out
    assert (folder / "history.png").read_bytes().startswith(PNG)
    assert (folder / "revision-0-residual-map.png").read_bytes().startswith(PNG)

    code, out, err = run(capsys, "study", "diagnose", folder, *EFFORT)
    assert code == 0, err
    assert out.splitlines()[1].startswith("1. clearance:"), out
    assert (folder / "diagnosis-0-stiffness.png").read_bytes().startswith(PNG)
    assert json.loads((folder / "diagnosis-0.json").read_text())["found"] is True
    best = json.loads(re.search(r"--add '(.*)'", out)[1])
    assert (best["kind"], best["dof"], best["ref"]) == ("clearance", "x4", "x5")

    code, out, err = run(capsys, "study", "revise", folder, "--add", json.dumps(best),
                         "--note", "clearance from the diagnosis")
    assert code == 0, err
    assert (folder / "revision-1-comparison.png").read_bytes().startswith(PNG)
    assert (folder / "revision-0-comparison.png").exists()  # earlier figures are kept

    code, out, _ = run(capsys, "study", "show", folder, "--json")
    history = json.loads(out)["history"]
    assert [row["note"] for row in history] == ["starting model",
                                                "clearance from the diagnosis"]
    # The hidden clearance causes most of the linear model's error (issue 7: >= 10 x).
    assert history[0]["nrmse_percent"] / history[1]["nrmse_percent"] >= REDUCTION

    code, _, err = run(capsys, "study", "revise", folder, "--add",
                       '{"kind": "clearance", "dof": "x9", "gap": 0.001}')
    assert code == 2
    assert "'x9'" in err and "not an output" in err
    code, out, _ = run(capsys, "study", "show", folder)
    # nothing lost: the two revisions' rows (each may be followed by its repairs)
    rows = [line for line in out.splitlines() if re.match(r"\s+\d+\s+\d+\s", line)]
    assert [row.split()[0] for row in rows] == ["0", "1"], out
    assert "offsets of the validation data" in out


def test_study_create_refuses_records_of_different_set_ups(records, tmp_path, capsys):
    fewer = tmp_path / "fewer.npz"
    Measurement.from_npz(records[1]).select(outputs=["x1", "x2"]).to_npz(fewer)
    code, _, err = run(capsys, "study", "create", records[0], fewer, "-o", tmp_path / "s",
                       *IDENTIFICATION)
    assert code == 2
    assert "output_names" in err and "same test set-up" in err
    assert not (tmp_path / "s").exists()


@pytest.mark.parametrize("warping", [False, True])
def test_identify_with_and_without_frequency_warping(records, tmp_path, capsys, warping):
    stop = json.dumps({"kind": "clearance", "dof": "x4", "ref": "x5",
                       "gap_negative": 0.002, "gap_positive": 0.001})
    flag = ["--frequency-warping"] if warping else []
    code, _, err = run(capsys, "identify", records[0], *IDENTIFICATION, "--element", stop,
                       *flag, "-o", tmp_path / "warped")
    assert code == 0, err
    result = json.loads((tmp_path / "warped" / "result.json").read_text())
    assert result["settings"]["frequency_warping"] is warping
    # a wide band: either variable identifies the stop (observed 0.10 % in z, 0.43 % in w)
    assert result["coefficients"][0]["mean_real"] == pytest.approx(1e4, rel=0.01)


# Every format through `fnsi info`, read by the same code as the service's uploads; the
# record of tests.service.formats: 1 kHz, 4 periods of 500 samples, force -> 2 outputs.
FILES = {
    "csv": (lambda d: formats.write_csv(formats.make_record(), d / "r.csv"),
            ["--fs", "1000", "--inputs", "force"]),
    "mat-v5": (lambda d: formats.write_mat_v5(formats.make_record(), d / "r.mat"), []),
    "mat-v7.3": (lambda d: formats.write_mat_v73(formats.make_record(), d / "r.mat"), []),
    "h5": (lambda d: formats.write_h5(formats.make_record(), d / "r.h5"), []),
    "uff": (lambda d: formats.write_uff(formats.make_record(), d / "r.uff", binary=True), []),
}


@pytest.mark.parametrize("kind", list(FILES))
def test_info_reads_every_format(kind, tmp_path, capsys):
    write, options = FILES[kind]
    code, out, err = run(capsys, "info", write(tmp_path), *options)
    assert code == 0, err
    summary = json.loads(out)
    assert (summary["inputs"], summary["outputs"]) == (["force"], ["NC2w_Z", "NC2b_Z"])
    assert (summary["fs"], summary["samples"], summary["periods"]) == (1000.0, 2000, 4)


def test_info_refuses_what_the_service_refuses(tmp_path, capsys):
    """The CLI's errors are the library's: a CSV without its rate, an HDF5 dataset stored
    in a file outside it."""
    code, _, err = run(capsys, "info", FILES["csv"][0](tmp_path))
    assert code == 2 and "sampling rate and the input columns" in err
    path = tmp_path / "external.h5"
    with h5py.File(path, "w") as f:
        f.create_dataset("u", data=np.ones((8, 1)))
        f.create_dataset("y", shape=(8, 1), dtype="f8", external=[("/etc/passwd", 0, 64)])
        f.attrs["fs"] = 10.0
    code, out, err = run(capsys, "info", path)
    assert code == 2 and "external storage" in err and out == ""


def _flags(options: dict) -> list[str]:
    """The CLI flags of an upload's meta."""
    words = []
    for key, value in options.items():
        if key == "units":
            value = ",".join(f"{name}={unit}" for name, unit in value.items())
        elif isinstance(value, list):
            value = ",".join(value)
        words += [f"--{key}", str(value)]
    return words


@pytest.mark.parametrize("case", list(formats.LAYOUTS))
def test_info_reads_or_refuses_each_layout_as_the_service_does(case, tmp_path, capsys):
    """The layout cases of tests/service/test_dataset_layouts.py, read by ``fnsi info``."""
    layout = formats.LAYOUTS[case]
    code, out, err = run(capsys, "info", layout.write(tmp_path), *_flags(layout.options))
    if layout.status != 201:
        assert code == 2 and out == "", out
        assert all(word in err.lower() for word in layout.says), err
        return
    assert code == 0, err
    summary = json.loads(out)
    summary["units"] = {name: unit or None for name, unit in zip(
        summary["inputs"] + summary["outputs"],
        summary["input_units"] + summary["output_units"], strict=True)}
    for field, value in layout.fields.items():
        assert summary[field] == value, field
