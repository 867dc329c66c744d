"""One-page HTML reports written by the ``fnsi`` command line, read as a person would.

The reports of an identification, a distortion analysis and a study (with a diagnosis
and a revision that cannot be simulated) of the 5-DOF chain with a hidden clearance
(:mod:`tests.fnsi.test_diagnosis`) are checked for self-containment (no reference to
anything outside the file), for their tables, and rendered in headless Chromium: every
image loads, nothing is logged as an error, the screenshot is not blank, the page prints.
"""

from __future__ import annotations

import html
import io
import json
import re
from html import escape
from pathlib import Path

import numpy as np
import pytest
from matplotlib.image import imread

from fnsi.cli import main
from tests.chromium import CHROMIUM, MISSING, render
from tests.fnsi.test_cli import EFFORT, HIDDEN, IDENTIFICATION
from tests.fnsi.test_diagnosis import chain, measure
from tests.fnsi.test_study_plots import failed_share

# An order far above what 5 DOFs support, with a stiff 1 mm clearance: the contact loop
# through the extra poles diverges (the linear part alone simulates: its unstable poles
# are reflected and it starts from its periodic state).
UNSTABLE = ["--order", "40", "--add",
            '{"kind": "clearance", "dof": "x4", "ref": "x5", "gap": 0.001}']


@pytest.fixture(scope="module")
def folders(tmp_path_factory) -> dict[str, Path]:
    """CLI output folders: an identification, an analysis and a study."""
    root = tmp_path_factory.mktemp("reports")
    model = chain(HIDDEN)
    records = root / "estimation.npz", root / "validation.npz"
    for seed, path in zip((1, 2), records, strict=True):
        measure(model, seed).to_npz(path)
    words = [["identify", records[0], *IDENTIFICATION, "-o", root / "identification"],
             ["analyse", records[0], "-o", root / "analysis"],
             ["study", "create", *records, *IDENTIFICATION, "-o", root / "study"],
             ["study", "diagnose", root / "study", *EFFORT]]
    for command in words:
        assert main([str(w) for w in command]) == 0, command
    return {name: root / name for name in ("identification", "analysis", "study")}


def drawn_share(pixels: np.ndarray) -> float:
    """Share of the pixels (RGB in [0, 1]) that are clearly not white."""
    return float(np.mean(pixels.min(axis=-1) < 0.9))


def images(page: str) -> list[str]:
    return re.findall(r"<img src=\"([^\"]*)\"", page)


@pytest.mark.parametrize("name", ["identification", "analysis", "study"])
def test_every_report_is_self_contained(folders, name):
    page = (folders[name] / "report.html").read_text()
    sources = images(page)
    assert sources and all(s.startswith("data:image/png;base64,") for s in sources)
    # nothing loaded from elsewhere: no script, stylesheet, link or URL of any kind
    assert not re.search(r"<script|<link|https?:|url\(|file:", page, re.IGNORECASE)
    # every figure of the folder is on the page (the study's diagnosis figures too)
    pngs = list(folders[name].glob("*.png"))
    assert len(sources) == len(pngs), (len(sources), [p.name for p in pngs])


def test_the_identification_report_tabulates_the_result(folders, capsys):
    page = (folders["identification"] / "report.html").read_text()
    result = json.loads((folders["identification"] / "result.json").read_text())
    assert f"Model of order {result['order']}" in page
    for mode in result["modes"]:
        assert f"<td>{mode['frequency_hz']:.4g}</td>" in page
    for channel in result["errors"]["estimation"]["channels"]:
        assert f"<td>{channel['nrmse_percent']:.4g}</td>" in page
    # the 0 Hz line left out of the comparison, named with its unit (none given here)
    x1 = result["errors"]["estimation"]["offsets"]["outputs"][0]
    assert "Offsets of the estimation data" in page
    assert f"x1 {x1['offset']:.3g} output unit" in page


def test_the_study_report_shows_revisions_diagnoses_and_failures(folders, capsys):
    folder = folders["study"]
    assert main(["study", "revise", str(folder), *UNSTABLE, "--note", "far too many modes"]) == 0
    out = capsys.readouterr().out
    assert f"wrote in {folder}/: report.html" in out
    page = (folder / "report.html").read_text()
    study = json.loads((folder / "study.json").read_text())
    diagnosis = json.loads((folder / "diagnosis-0.json").read_text())
    failed = study["revisions"][-1]
    assert failed["failure"], "meant to give a model that cannot be simulated"
    for revision in study["revisions"]:
        assert f"Revision {revision['number']}: {revision['note']}" in page
    assert "Diagnosis of revision 0" in page and html.escape(diagnosis["summary"]) in page
    assert escape(f"the model could not be simulated: {failed['failure']}") in page
    assert "<td class=\"text\">failed</td>" in page  # the history row of the failed one
    assert "Offsets of the validation data" in page
    assert failed_share((folder / "history.png").read_bytes()) > 0.005  # drawn as failed


@pytest.mark.skipif(CHROMIUM is None, reason=MISSING)
@pytest.mark.parametrize("name", ["identification", "analysis", "study"])
def test_every_report_renders_in_chromium(folders, name):
    path = folders[name] / "report.html"
    rendering = render(path)
    assert len(rendering.images) == len(images(path.read_text()))
    assert all(i["complete"] and i["naturalWidth"] > 0 for i in rendering.images), \
        rendering.images
    assert rendering.errors == []
    pixels = imread(io.BytesIO(rendering.screenshot))[..., :3]
    # not blank: figures and text make a large share of non-white pixels of many shades
    assert pixels.shape[0] > 900 and drawn_share(pixels) > 0.02
    assert len(np.unique(pixels.reshape(-1, 3), axis=0)) > 100
    assert rendering.pdf.startswith(b"%PDF") and rendering.pdf.count(b"/Type /Page") >= 1


@pytest.mark.skipif(CHROMIUM is None, reason=MISSING)
def test_the_chromium_check_sees_broken_images_and_errors(tmp_path):
    """The checks above can fail: a truncated PNG and a script error are seen."""
    page = tmp_path / "broken.html"
    page.write_text("<!DOCTYPE html><html><body><img src=\"data:image/png;base64,iVBORw0K\">"
                    "<script>console.error('drawn wrong'); undefined_name();</script>"
                    "</body></html>")
    rendering = render(page)
    assert rendering.images[0]["naturalWidth"] == 0
    assert any("drawn wrong" in e for e in rendering.errors)
    assert any("undefined_name" in e or "Uncaught" in e for e in rendering.errors), \
        rendering.errors
    assert drawn_share(imread(io.BytesIO(rendering.screenshot))[..., :3]) < 0.02  # blank
