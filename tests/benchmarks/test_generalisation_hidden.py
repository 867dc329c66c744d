"""The hidden-effect half of the generalisation benchmark (issue 21): its generator sizes
effects into the band, writes no truth where the library looks, and leaves a no-effect
case linear; its scorer reads kinds, locations and stop sides as documented; its oracle
maps the truth into the library's elements and waits for the answers."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from benchmarks.generalisation import hidden, oracle, synthesis
from benchmarks.generalisation.blind import answer_path, blindfold, truth_path, write_json
from benchmarks.generalisation.cases import Setup
from benchmarks.generalisation.hidden_scoring import (
    claim,
    report,
    score_hidden,
    score_hidden_case,
    truth_claim,
)
from benchmarks.generalisation.structures import GROUND, Structure

# 2-DOF chain, both masses damped (poles decaying at 2-3 / s: a few periods to steady state)
M2 = np.diag([1.0, 2.0])
K2 = np.array([[3000.0, -1000.0], [-1000.0, 1000.0]])
C2 = np.diag([6.0, 6.0])


def _setup() -> tuple[Setup, np.ndarray]:
    fs, samples = 64.0, 128
    lines = synthesis.excited_lines(samples, fs, (2.0, 12.0))
    rng = np.random.default_rng(4)
    spectrum = synthesis.multisine(rng, 1, samples, lines, 1)
    structure = Structure("chain", "nonproportional", False, ((0, GROUND), (1, 0)), M2, C2, K2)
    setup = Setup(structure, (2.0, 12.0), fs, samples, lines, np.array([1]), np.array([0, 1]),
                  "displacement", 1, 0.0, spectrum)
    return setup, synthesis.multisine(rng, 1, samples, lines, 1)


@pytest.mark.parametrize("kind", ["cubic_hardening", "stop"])
def test_sizing_lands_in_the_target_band(kind):
    # the sized effect's linear error, recomputed with the records' tight integrator
    # settings, is within the sizing's acceptance (a factor 1.5 of the target) up to the
    # loose sizing integration (1e-4 periodicity: 2 % slack), and inside the band
    # on both records: the smaller error is sized, so the effect shows in each
    setup, validation = _setup()
    records = tuple(hidden.Record(s, hidden._respond(setup, s, (), hidden.RECORD))
                    for s in (validation, setup.spectrum))
    motion = hidden._linear_motion(setup, validation)
    draft = hidden.Draft(kind, 0, GROUND, float(K2[0, 0]), 1.0, 0.05, 1.0)
    p, error = hidden.size(draft, 12.0, setup, records, motion)
    tight = [hidden.linear_error(hidden._respond(setup, r.spectrum,
                                                 (draft.element(p, motion),), hidden.RECORD),
                                 r.linear) for r in records]
    assert tight[0] == pytest.approx(error, rel=0.02)
    assert 12.0 / 1.5 / 1.02 <= min(tight) <= 12.0 * 1.5 * 1.02
    assert all(hidden.ERROR_BAND[0] < e < hidden.ERROR_BAND[1] for e in tight)


def test_stronger_effect_misses_the_linear_model_more():
    # the bisection relies on the error growing with the strength p, for every kind
    setup, validation = _setup()
    records = (hidden.Record(validation, hidden._respond(setup, validation, (), hidden.RECORD)),)
    motion = hidden._linear_motion(setup, validation)
    for kind in hidden.KINDS:
        draft = hidden.Draft(kind, 1, 0, float(K2[1, 1]), 1.0, 0.5, -1.0)
        errors = [hidden._errors(setup, records, (draft.element(p, motion),))[0]
                  for p in (0.05, 0.5)]
        assert 0 < errors[0] < errors[1], kind


def test_a_single_sensor_offers_one_location_and_two_effects_need_two():
    # a pair drawn on one sensor searched forever for a second free location (seed 1021,
    # case 28 hung the generator); one sensor to ground is its only location
    setup, _ = _setup()
    one = dataclasses.replace(setup, sensors=np.array([1]))
    assert hidden._location_count(one) == 1 and hidden._location_count(setup) == 3
    rng = np.random.default_rng(0)
    first = hidden._draw_draft(rng, one, set())
    assert (first.dof, first.ref) == (1, GROUND)


def test_no_effect_case_is_linear_and_keeps_its_truth_out_of_the_data():
    # case 3 of seed 21 draws no effect: its records are the exact linear synthesis
    # (noise free: equal to rounding) and the truth holds no element
    seed = np.random.SeedSequence(21).spawn(4)[3]
    data, truth = hidden.draw_hidden_case(seed, noise_free=True)
    assert truth["elements"] == [] and truth["plan"]["effects"] == 0
    assert set(data) == {"u", "y", "u_validation", "y_validation", "fs", "periods",
                         "quantity", "band", "input_names", "output_names"}
    s = truth["structure"]
    period = truth["plan"]["samples_per_period"]
    spectrum = np.fft.rfft(data["u_validation"][:, :period], axis=1)  # the forces' lines
    lines = np.flatnonzero(np.abs(spectrum[0, :, 0]) > 1e-9 * np.abs(spectrum).max())
    _, y = synthesis.steady_state(np.array(s["M"]), np.array(s["C"]), np.array(s["K"]),
                                  spectrum, period, lines, float(data["fs"]),
                                  np.array(s["sensor_dofs"]), np.array(s["input_dofs"]),
                                  str(data["quantity"]))
    assert np.allclose(data["y_validation"][:, :period], y, rtol=0, atol=1e-9 * np.abs(y).max())


def test_truth_is_sealed_until_every_answer_is_recorded(tmp_path):
    truth_path(tmp_path).parent.mkdir(parents=True)
    truth_path(tmp_path).write_text('{"cases": {}}')
    (tmp_path / "cases").mkdir()
    (tmp_path / "cases" / "index.json").write_text(
        '{"seed": 1, "count": 1, "part": "hidden", "cases": ["case0000"]}')
    with pytest.raises(ValueError, match="1 of 1 cases have no answer"):
        score_hidden(tmp_path)
    with blindfold(tmp_path), pytest.raises(PermissionError, match="sealed"):
        truth_path(tmp_path).read_text()


def _draw_or_refuse(seed: np.random.SeedSequence, *, noise_free: bool = False):
    """Stands for :func:`hidden.draw_hidden_case`: case 1 cannot be sized."""
    if seed.spawn_key[-1] == 1:
        raise RuntimeError("no effect could be sized into the band")
    return {"u": np.zeros(4)}, {"plan": {"kinds": []}, "elements": []}


def test_a_case_that_cannot_be_drawn_is_skipped_and_the_others_kept(tmp_path, monkeypatch):
    # the pool forks: its processes see the patched module
    monkeypatch.setattr(hidden, "draw_hidden_case", _draw_or_refuse)
    drawn = hidden.generate_hidden(tmp_path, 5, 3, jobs=1)
    index = json.loads((tmp_path / "cases" / "index.json").read_text())
    assert drawn == index["cases"] == ["case0000", "case0002"]
    assert index["skipped"] == {"case0001": "no effect could be sized into the band"}
    assert sorted(json.loads(truth_path(tmp_path).read_text())["cases"]) == drawn
    assert not (tmp_path / "cases" / "case0001.npz").exists()


def test_claims_read_kind_location_and_stop_side_in_the_truths_orientation():
    # a stop between x2 and x0 on the positive side of x0 - x2 is the negative side of
    # x2 - x0; a stop to ground keeps its side; a two-sided clearance has no side
    truth = {"dof": 0, "ref": 2, "kind_class": "stop", "gaps": [math.inf, 0.1]}
    reversed_stop = {"effect": "clearance", "location": {"dof": "x2", "ref": "x0"},
                     "element": {"kind": "clearance", "gap_negative": 0.1, "side": "negative"}}
    assert claim(reversed_stop) == truth_claim(truth)
    other_side = {"kind": "clearance", "gap_positive": 0.1, "side": "positive"}
    assert claim({**reversed_stop, "element": other_side}) != truth_claim(truth)
    ground = {"effect": "clearance", "location": {"dof": "x3", "ref": None},
              "element": {"kind": "clearance", "gap": 0.2, "side": "both"}}
    assert claim(ground) == ("clearance", frozenset((3, GROUND)), None)
    assert claim({"effect": "missing_mode", "location": None, "element": None}) == (
        "missing_mode", frozenset(), None)


def test_a_clearance_gap_beyond_the_measured_motion_makes_a_stop():
    # +-1.5 at x3 moving over [-1, 2]: only the positive side is ever in contact
    ground = {"effect": "clearance", "location": {"dof": "x3", "ref": None},
              "element": {"kind": "clearance", "gap": 1.5, "side": "both"}}
    motion = {"x3": np.array([-1.0, 0.0, 2.0])}
    assert claim(ground, motion) == ("stop", frozenset((3, GROUND)), "positive")
    assert claim(ground, {"x3": np.array([-2.0, 2.0])})[0] == "clearance"


def test_revision_0_worse_than_the_truth_says_both_records():
    """A linear revision that validates at 95.8 % where the true linear structure does at
    26.9 % is flagged; the flag also gives both errors on the estimation record (2.4 %
    against 25 %: it fitted that record's distortion), and says nothing of them for an
    answer recorded before they were."""
    truth = {"plan": {"effects": 1, "kinds": ["quadratic"], "linear_error_pct": 26.9,
                      "linear_estimation_error_pct": 25.0}, "elements": []}
    answer = {"status": "ok", "noise_floor_pct": 0.88, "estimation_pct": 2.39, "rounds": [],
              "revisions": [{"order": 34, "nrmse_pct": 95.8, "failure": None}]}
    flags = dict(score_hidden_case("case0013", truth, answer).problems)
    assert flags["revision 0 worse than the true linear structure"] == (
        "95.8 % against 26.9 % (order 34); estimation record 2.39 % against 25 %")
    del answer["estimation_pct"]
    flags = dict(score_hidden_case("case0013", truth, answer).problems)
    assert flags["revision 0 worse than the true linear structure"].endswith("(order 34)")


def test_a_failure_lists_the_studys_warnings():
    """The study's warnings (here: inputs its realisations do not tell apart) are quoted
    beside the failure they may explain; an answer recorded before them has none."""
    plan = {"effects": 1, "kinds": ["quadratic"], "locations": ["ground, far"],
            "linear_error_pct": 26.9, "topology": "chain", "dofs": 8,
            "damping": "proportional", "close_modes": False, "quantity": "displacement",
            "inputs": 2, "sensors": 1, "noise_pct": 1.2, "fs_ratio": 4.18}
    warning = "the 2 realisations' inputs are nearly parallel on 11 % of the band's lines"
    answer = {"status": "ok", "noise_floor_pct": 0.88, "rounds": [], "warnings": [warning],
              "revisions": [{"order": 34, "nrmse_pct": 95.8, "failure": None}]}
    score = score_hidden_case("case0013", {"plan": plan, "elements": []}, answer)
    assert score.warnings == [warning]
    assert f"  - the study warned: {warning}" in report([score], 32, "", None).splitlines()
    del answer["warnings"]
    assert score_hidden_case("case0013", {"plan": plan, "elements": []}, answer).warnings == []


def test_a_claim_made_once_the_truth_is_in_the_model_is_flagged():
    """The loop's second round claiming a damper after the true cubic spring was claimed
    is an invention the headline does not count (top-1 and the floor read the first
    claim and the last error): it gets its own category. A pair's second claim, and a
    wrong first claim followed by the truth, are not inventions after the truth."""
    truth = {"plan": {"effects": 1, "kinds": ["cubic_hardening"], "linear_error_pct": 20.0},
             "elements": [{"dof": 2, "ref": -1, "kind_class": "cubic_stiffness"}]}
    cubic = {"effect": "cubic_stiffness", "location": {"dof": "x2", "ref": None},
             "element": {"kind": "polynomial"}}
    damper = {"effect": "quadratic_damping", "location": {"dof": "x3", "ref": None},
              "element": {"kind": "quadratic_damping"}}

    def flags(*claimed: dict) -> dict:
        answer = {"status": "ok", "noise_floor_pct": 0.5,
                  "rounds": [{"diagnosis_s": 1.0, "found": True, "summary": "",
                              "nrmse_before_pct": 20.0, "candidates": [c]}
                             for c in claimed],
                  "revisions": [{"order": 8, "nrmse_pct": e, "failure": None, "note": ""}
                                for e in (20.0, 0.8, 0.7)[: len(claimed) + 1]]}
        return dict(score_hidden_case("case0001", truth, answer).problems)

    assert flags(cubic, damper)["claimed beyond the truth"] == (
        "claimed quadratic_damping at x3-ground once the true cubic_stiffness at "
        "x2-ground was claimed (error 20 % -> 0.7 %, floor 0.5 %)")
    assert "claimed beyond the truth" not in flags(cubic)
    assert "claimed beyond the truth" not in flags(damper, cubic)


def test_a_pair_claimed_in_one_round_finds_both_effects():
    """A top candidate claimed together with its partner (both added in one round) names
    both hidden effects: the pair is found and the first decides top-1; a partner at the
    wrong place leaves the pair incomplete."""
    truth = {"plan": {"effects": 2, "kinds": ["quadratic_damping", "clearance"],
                      "linear_error_pct": 6.0},
             "elements": [{"dof": 0, "ref": -1, "kind_class": "quadratic_damping"},
                          {"dof": 0, "ref": 2, "kind_class": "clearance"}]}
    damper = {"effect": "quadratic_damping", "location": {"dof": "x0", "ref": None},
              "element": {"kind": "quadratic_damping"}}

    def score(partner_ref: str):
        clearance = {"effect": "clearance", "location": {"dof": "x0", "ref": partner_ref},
                     "element": {"kind": "clearance", "gap": 1e-3}}
        top = {**damper, "partner": clearance}
        answer = {"status": "ok", "noise_floor_pct": 0.43,
                  "rounds": [{"diagnosis_s": 1.0, "found": True, "summary": "",
                              "nrmse_before_pct": 6.14, "candidates": [top]},
                             {"diagnosis_s": 1.0, "found": False, "summary": "",
                              "nrmse_before_pct": 0.5, "candidates": []}],
                  "revisions": [{"order": 8, "nrmse_pct": e, "failure": None, "note": ""}
                                for e in (6.14, 0.5)]}
        return score_hidden_case("case0003", truth, answer)

    found = score("x2")
    assert found.top1 and found.pair_found and found.floor_reached
    missed = score("x1")
    assert missed.top1 and not missed.pair_found
    assert "pair not completed" in dict(missed.problems)


def test_oracle_maps_the_truth_into_the_libraries_elements_and_coordinate():
    # a contact below -g- and above g+ of the rest position is below -(g- + c) and above
    # g+ - c of a coordinate whose zero is c above rest (module docstring of .oracle)
    both = {"kind": "clearance", "dof": 2, "ref": 0, "gaps": [0.3, 0.5]}
    element = oracle.library_element(both, 0.1)
    assert (element.dof, element.ref) == ("x2", "x0")
    assert element.gaps == pytest.approx((0.4, 0.4))
    stop = oracle.library_element({"kind": "clearance", "dof": 1, "ref": GROUND,
                                   "gaps": [math.inf, 0.5]}, -0.2)
    assert (stop.side, stop.ref, stop.gaps[1]) == ("positive", None, pytest.approx(0.7))
    cubic = oracle.library_element({"kind": "cubic", "dof": 1, "ref": GROUND})
    quadratic = oracle.library_element({"kind": "quadratic", "dof": 1, "ref": GROUND})
    assert (cubic.exponent, cubic.signed, quadratic.exponent, quadratic.signed) == (
        3.0, True, 2.0, False)
    friction = oracle.library_element({"kind": "coulomb", "dof": 1, "ref": 0, "width": 0.01})
    assert (friction.kind, friction.width) == ("coulomb_friction", 0.01)


def test_oracle_waits_for_the_answers_then_tells_diagnosis_from_identification(tmp_path):
    cases = ["case0000", "case0001", "case0002"]
    (tmp_path / "cases").mkdir()
    (tmp_path / "cases" / "index.json").write_text(json.dumps(
        {"seed": 1, "count": 3, "part": "hidden", "cases": cases}))
    element = {"kind": "cubic", "kind_class": "cubic", "dof": 0, "ref": GROUND}
    truth = {c: {"elements": [element], "plan": {"quantity": "velocity"}} for c in cases}
    truth_path(tmp_path).parent.mkdir()
    truth_path(tmp_path).write_text(json.dumps({"cases": truth}))
    with pytest.raises(ValueError, match="no answer"):
        oracle.run_oracle(tmp_path)
    # loop at the floor; loop off but the truth at the floor; both off (floor 1 %)
    for case, loop, true in zip(cases, (1.5, 9.0, 9.0), (1.2, 1.9, 5.0), strict=True):
        write_json(answer_path(tmp_path, case),
                   {"status": "ok", "revisions": [{"nrmse_pct": loop}]})
        write_json(oracle.oracle_path(tmp_path, case),
                   {"status": "ok", "noise_floor_pct": 1.0, "linear_pct": 10.0,
                    "oracle_pct": true})
    _, totals = oracle.oracle_report(tmp_path)
    assert totals == {"cases": 3, "loop_floor_reached": 1, "oracle_floor_reached": 2,
                      "diagnosis_limited": 1, "identification_limited": 1}
