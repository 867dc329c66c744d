"""Exports read back by other tools: the modes' UFF 55 by pyuff, the MAT file by SciPy.

The files are those ``fnsi identify`` writes for the 5-DOF chain with a hidden
clearance (:mod:`tests.fnsi.test_diagnosis`), compared with its ``result.json``.
"""

from __future__ import annotations

import io
import json

import numpy as np
import pytest
import pyuff
from scipy.io import loadmat

from fnsi.cli import main
from fnsi.export import result_mat, uff_nodes
from tests.fnsi.test_cli import HIDDEN, IDENTIFICATION
from tests.fnsi.test_diagnosis import chain, measure

# UFF 55 writes its values as E13.5 (6 significant digits): relative error below 1e-5.
UFF_RTOL = 1e-5


@pytest.fixture(scope="module")
def identified(tmp_path_factory):
    folder = tmp_path_factory.mktemp("export")
    measure(chain(HIDDEN), 1).to_npz(folder / "record.npz")
    element = json.dumps({"kind": "clearance", "dof": "x4", "ref": "x5",
                          "gap_negative": 0.002, "gap_positive": 0.001})
    assert main(["identify", str(folder / "record.npz"), *IDENTIFICATION,
                 "--element", element, "-o", str(folder / "out")]) == 0
    out = folder / "out"
    return out, json.loads((out / "result.json").read_text())


def test_pyuff_reads_every_mode_back(identified):
    folder, result = identified
    sets = pyuff.UFF(str(folder / "modes.uff")).read_sets()
    sets = sets if isinstance(sets, list) else [sets]
    assert len(sets) == len(result["modes"]) >= 3
    for number, (read, mode) in enumerate(zip(sets, result["modes"], strict=True), start=1):
        assert read["type"] == 55 and read["analysis_type"] == 3 and read["mode_n"] == number
        eig = read["eig"]
        np.testing.assert_allclose(abs(eig) / (2 * np.pi), mode["frequency_hz"], rtol=UFF_RTOL)
        np.testing.assert_allclose(-eig.real / abs(eig), mode["damping_ratio"], rtol=1e-4)
        shape = np.array([re + 1j * im for re, im in mode["shape"]])
        # outputs x1..x5 are nodes 1..5 along direction 1
        np.testing.assert_array_equal(read["node_nums"], np.arange(1, 6))
        np.testing.assert_allclose(read["r1"], shape, rtol=0,
                                   atol=UFF_RTOL * np.max(np.abs(shape)))
        assert np.all(read["r2"] == 0) and np.all(read["r3"] == 0)


def test_scipy_reads_the_result_back(identified):
    folder, result = identified
    mat = loadmat(folder / "result.mat")
    np.testing.assert_array_equal(mat["frequency_hz"].ravel(),
                                  [m["frequency_hz"] for m in result["modes"]])
    shapes = np.array([[re + 1j * im for re, im in m["shape"]] for m in result["modes"]]).T
    np.testing.assert_array_equal(mat["shapes"], shapes)
    assert [c[0] for c in mat["output_names"].ravel()] == result["output_names"]
    np.testing.assert_array_equal(mat["A"], np.array(result["model"]["A"]))
    assert int(mat["order"].item()) == result["order"]
    errors = [c["nrmse_percent"] for c in result["errors"]["estimation"]["channels"]]
    np.testing.assert_array_equal(mat["nrmse_percent_estimation"].ravel(), errors)
    names = [c[0] for c in mat["coefficient_names"].ravel()]
    assert names == [c["name"] for c in result["coefficients"]]


def test_smallsat_names_share_nodes_one_direction_each():
    names, places = uff_nodes(["NC2w_Z", "NC2b_Z", "NC2w_X", "W_y", "strain"])
    assert names == ["NC2w", "NC2b", "W", "strain"]
    assert places == [(0, 2), (1, 2), (0, 0), (2, 1), (3, 0)]
    with pytest.raises(ValueError, match="same node and direction"):
        uff_nodes(["a_X", "a_x"])


def test_a_result_without_modes_still_exports_its_mat_file():
    document = {"modes": [], "output_names": ["x1"], "order": 2, "coefficients": [],
                "warnings": ["no mode in the band"], "errors": {"estimation": {
                    "failure": "unstable"}}}
    mat = loadmat(io.BytesIO(result_mat(document)))
    assert mat["shapes"].shape == (1, 0)
    assert np.isnan(mat["nrmse_percent_estimation"]).all()
