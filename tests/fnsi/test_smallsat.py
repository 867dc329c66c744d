"""SmallSat-like reference model: Table 1 modes and the regimes of Tables 3 and 8."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fnsi import smallsat
from fnsi.nonlinear import NonlinearityKind


@pytest.fixture(scope="module")
def modes():
    """Linear modes of the tuned model with the describing quantities of each."""
    table = smallsat.smallsat_model().linear_modes()
    return table, [smallsat.describe_mode(shape) for shape in table.shapes[:12]]


@pytest.fixture(scope="session")
def multi():
    """Paper IV.C: 200 N RMS at W along the X-Y diagonal."""
    return smallsat.simulate_preset("multi")


TABLE_F = np.array([row[0] for row in smallsat.TABLE_1])
TABLE_Z = np.array([row[1] for row in smallsat.TABLE_1]) / 100.0


def test_first_eleven_frequencies_within_two_percent_of_table_1(modes):
    table, _ = modes
    # 2 %: the tuning target of issue 4 (Table 1 is given to 4 digits).
    np.testing.assert_allclose(table.frequencies[:11], TABLE_F, rtol=0.02)


def test_twelfth_mode_above_the_band_of_table_1(modes):
    table, _ = modes
    # Table 1 lists all modes up to 50 Hz: ours has no twelfth mode below it.
    assert table.frequencies[11] > 50.0


def test_damping_ratios_within_twenty_percent_of_table_1(modes):
    table, _ = modes
    # 20 %: the tuning target (a few lumped dashpots cannot match 11 values exactly).
    np.testing.assert_allclose(table.damping_ratios[:11], TABLE_Z, rtol=0.20)


def test_damping_is_not_proportional(modes):
    table, _ = modes
    # Proportional damping gives real modes: 1 - |phi^T phi| / phi^H phi (the modal
    # complexity) would be 0 to round-off; the WEMS dashpots make the WMP modes complex.
    shapes = table.shapes[:6]
    complexity = 1 - np.abs(np.sum(shapes**2, axis=1)) / np.sum(np.abs(shapes) ** 2, axis=1)
    assert complexity.max() > 0.01


def test_wems_modes_are_wmp_motions_of_table_1(modes):
    _, d = modes
    # Modes 1-6: more than half the kinetic energy in the WEMS mobile part, and of its
    # rigid-body energy more than half in the family Table 1 names.
    for k, family in enumerate(("X", "Y", "X", "Y", "Z", "RZ")):
        assert d[k]["wmp"] > 0.5, k + 1
        assert d[k][f"wmp_{family}"] > 0.5, k + 1
    assert d[0]["wmp_phase_X"] > 0 and d[1]["wmp_phase_Y"] > 0     # concave
    assert d[2]["wmp_phase_X"] < 0 and d[3]["wmp_phase_Y"] < 0     # convex
    # Mode 5 bends the bracket: its NC nodes move at least a tenth as much as the WMP's.
    assert d[4]["bracket_motion"] > 0.1


def test_structure_modes_are_panel_and_main_motions_of_table_1(modes):
    _, d = modes
    # Modes 7-11: more than half the kinetic energy in the instrument panel (IP) and
    # telescope, each a rigid motion of the IP of the family Table 1 names.
    for k in range(6, 11):
        assert d[k]["panel"] > 0.5, k + 1
    assert d[6]["panel_Y"] > 0.5                       # 7: tilts about X
    assert d[7]["panel_X"] > 0.5                       # 8: perpendicular, about Y ...
    assert d[7]["wmp_Z"] > 0.5                         # ... moving the WMP along Z
    assert d[8]["panel_RZ"] > 0.5                      # 9: rotation about Z
    # 10: in-plane motion of the IP with the main structure in phase.
    assert d[9]["panel_X"] > 0.5 and d[9]["panel_top_phase"] > 0.5
    assert d[9]["main"] > 0.01
    assert d[10]["panel_rotation"] > 0.5               # 11: tilts the IP


def test_wems_stops_follow_table_2():
    elements = smallsat.wems_elements()
    assert len(elements) == 8 and all(e.kind is NonlinearityKind.CLEARANCE for e in elements)
    axial = [e for e in elements if e.dof.endswith("_Z")]
    lateral = [e for e in elements if not e.dof.endswith("_Z")]
    assert [e.dof for e in lateral] == ["NC1w_X", "NC2w_X", "NC3w_Y", "NC4w_Y"]
    assert all(e.gaps == (1.5, 1.5) and e.coefficients == (100.0,) for e in axial)
    assert all(sorted(e.gaps)[0] == 2.0 and e.coefficients == (40.0,) for e in lateral)
    assert [e.side for e in lateral] == ["positive", "negative", "positive", "negative"]
    model = smallsat.smallsat_model()
    i, j = model.dof_index("NC2w_Z"), model.dof_index("NC2b_Z")
    assert model.K[i, j] == -8.0    # linear axial slope of Table 2, model units


def _count(truth, name: str) -> int:
    nc, axis = name.split("_")
    return truth.exceedances[f"clearance {nc}w_{axis}-{nc}b_{axis}"]


def test_single_preset_impacts_only_nc2_z(single):
    measurement, truth = single
    assert measurement.y.shape == (1, 240000, 39) and measurement.input_names == ("F_NC2w_Z",)
    counts = {name: _count(truth, name) for name in smallsat.TABLE_3}
    assert all(counts[name] == 0 for name in counts if name != "NC2_Z"), counts
    # Within 30 % of Table 3 (180,000 kept samples): a different structure and noise
    # realisation cannot reproduce the exact count.
    assert counts["NC2_Z"] == pytest.approx(smallsat.TABLE_3["NC2_Z"], rel=0.30)


def test_multi_preset_activates_all_eight_stops(multi):
    _, truth = multi
    for name, paper in smallsat.TABLE_8.items():
        # Factor 1.5: the paper's own counts differ by 1.5 between symmetric stops.
        assert paper / 1.5 <= _count(truth, name) <= paper * 1.5, (name, _count(truth, name))


def test_single_preset_input_is_the_papers_force_in_model_units(single):
    measurement, _ = single
    rms_n = measurement.u.std() * smallsat.FORCE_UNIT_N
    assert rms_n == pytest.approx(100.0, rel=1e-9)


def test_noise_is_half_a_percent_of_the_bracket_tip():
    short = {"periods": 3, "samples_per_period": 2500}
    clean, _ = smallsat.simulate_preset("single", noise_percent=0.0,
                                        outputs=("NC2w_Z", smallsat.BRACKET_TIP), **short)
    noisy, truth = smallsat.simulate_preset("single", outputs=("NC2w_Z",), **short)
    assert noisy.output_names == ("NC2w_Z",) and truth.modal.output_names == ("NC2w_Z",)
    noise = np.sqrt(np.mean((noisy.y[0, :, 0] - clean.y[0, :, 0]) ** 2))
    tip = np.sqrt(np.mean(clean.y[0, 5000:, 1] ** 2))   # the kept (third) period
    # Same seed, same excitation: the difference is the noise alone, scaled exactly.
    assert noise == pytest.approx(0.005 * tip, rel=1e-6)


def test_unknown_preset_is_refused():
    with pytest.raises(ValueError, match="single"):
        smallsat.simulate_preset("double")


@pytest.mark.parametrize(("changes", "says"), [
    ({"periods": 1}, "periods=1 leaves no period after the 2 transient"),
    ({"periods": 2}, "give periods >= 3"),
    ({"outputs": ("nope",)}, "unknown output channel 'nope'; outputs are .*'NC2w_Z'"),
    ({"outputs": ("W_Z", "W_Z")}, r"outputs \['W_Z'\] are chosen more than once"),
    ({"fs_int": 20001.0}, "fs_int=20001 Hz must be an integer multiple of fs=2500 Hz"),
    ({"fs": 80.0, "fs_int": 800.0}, "fs/2 = 40"),   # the 5-50 Hz band beyond Nyquist
    ({"samples_per_period": 20}, "at least 32"),
])
def test_a_preset_run_that_could_only_fail_is_refused_before_simulating(changes, says):
    arguments = {"periods": 3, "samples_per_period": 2500, "outputs": None, "fs": 2500.0,
                 "fs_int": 20000.0, **changes}
    with pytest.raises(ValueError, match="preset 'single': .*" + says):
        smallsat.check_preset("single", **arguments)
    with pytest.raises(ValueError, match=says):
        smallsat.simulate_preset("single", **arguments)


def test_parameters_with_missing_keys_are_refused():
    data = json.loads(smallsat.PARAMETERS_FILE.read_text())
    data.pop("arm_radius")
    with pytest.raises(ValueError, match="arm_radius"):
        smallsat.SmallSatParameters.from_json(data)
