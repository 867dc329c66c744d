"""Studies: revisions identified on estimation data and judged on validation data.

The structure is the 5-DOF chain of :mod:`tests.fnsi.test_diagnosis` with a hidden cubic
spring at x3; revision 0 is linear, revision 1 adds the cubic spring.
"""

from __future__ import annotations

import dataclasses
import json
import math
import types

import numpy as np
import pytest

from fnsi.diagnosis import DiagnosisSettings
from fnsi.nonlinear import NonlinearElement
from fnsi.study import Study, _find, law_name
from fnsi.study_plots import diagnosis_figures, residual_map, study_figures
from tests.fnsi.test_diagnosis import SETTINGS, chain, measure

CUBIC = NonlinearElement("polynomial", "x3", exponent=3.0)
PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="session")
def data():
    model = chain(NonlinearElement("polynomial", "x3", exponent=3.0, coefficients=(2e8,)))
    return measure(model, 1), measure(model, 2)


@pytest.fixture(scope="session")
def study(data):
    study = Study.create(*data, SETTINGS, connections=[("x2", "x4")], name="chain")
    study.add_revision(add=[CUBIC])
    return study


def test_revision_errors_per_channel_in_percent_and_db(study):
    linear, cubic = study.revisions
    errors = linear.errors
    assert errors.nrmse_percent.shape == (5,)
    np.testing.assert_allclose(errors.nrmse_db, 20 * np.log10(errors.nrmse_percent / 100))
    # The linear model misses the cubic spring: every channel is far above its floor;
    # with it, the model reaches the floor (within 3 x, the acceptance threshold).
    assert np.all(errors.nrmse_percent > 5 * errors.noise_floor_percent)
    assert cubic.nrmse_percent < 3 * cubic.noise_floor_percent
    # Frequency-domain error per channel and line, up to 3 x the band edge.
    assert errors.error_spectrum.shape == (errors.frequencies.size, 5)
    assert errors.frequencies.max() == pytest.approx(3 * SETTINGS.band[1], abs=0.5)
    excited = linear.excited
    in_band = (errors.frequencies >= 5.0) & (errors.frequencies <= 60.0)
    assert excited[in_band].mean() > 0.3 and not excited[~in_band].any()
    channel = study.to_json()["revisions"][0]["validation"]["channels"][2]
    assert channel["relative_to_noise_floor_db"] == pytest.approx(
        errors.nrmse_db[2] - errors.noise_floor_db[2])


def test_overall_errors_weight_channels_by_their_power(study):
    revision = study.revisions[0]
    power = study.channel_power
    expected = np.sqrt(np.sum(revision.errors.nrmse_percent**2 * power) / np.sum(power))
    assert revision.nrmse_percent == pytest.approx(expected, rel=1e-12)
    # The floor depends on the data only: the same for every revision, and the same as
    # the channels' floors pooled alike.
    floors = revision.errors.noise_floor_percent
    assert study.noise_floor_percent == pytest.approx(
        np.sqrt(np.sum(floors**2 * power) / np.sum(power)), rel=1e-9)
    assert study.revisions[1].noise_floor_percent == study.noise_floor_percent


def test_history_table_and_chart(study):
    rows = study.history()
    assert [r["number"] for r in rows] == [0, 1]
    assert rows[1]["note"] == "add cubic spring x3"      # labelled by its law
    assert rows[1]["elements"] == ["cubic spring x3"]
    assert rows[1]["nrmse_percent"] < rows[0]["nrmse_percent"] / 10
    table = study.history_table()
    assert "add cubic spring x3" in table and len(table.splitlines()) == 4
    # the last line names the offsets removed from the validation data (tiny here)
    assert table.splitlines()[-1].startswith("offsets of the validation data")
    figures = study_figures(study, 0)
    assert set(figures) == {"history.png", "revision-0-comparison.png",
                            "revision-0-residual-spectra.png", "revision-0-residual-map.png"}
    assert all(png.startswith(PNG) for png in figures.values())


def test_residual_map_points_at_the_failing_model(study):
    edges, before = residual_map(study.revisions[0], bands=8)
    _, after = residual_map(study.revisions[1], bands=8)
    assert before.shape == after.shape == (5, 8) and edges.size == 9
    # Linear model: residual 20 dB or more above the noise somewhere; with the cubic
    # spring the worst band is within 10 dB of the noise (floor within 3 x in NRMSE).
    assert np.nanmax(before) > 20.0
    assert np.nanmax(after) < np.nanmax(before) - 15.0


def test_remove_and_order_change_make_new_revisions(study, data):
    copy = Study.create(*data, SETTINGS)
    copy.add_revision(add=[CUBIC.to_json()])
    back = copy.add_revision(remove=[0])
    assert back.elements == () and back.note == "remove cubic spring x3"
    # Same model as revision 0: the identification is deterministic.
    assert back.nrmse_percent == pytest.approx(copy.revisions[0].nrmse_percent, rel=1e-9)
    bigger = copy.add_revision(order=12, base=1)
    assert bigger.identified_order == 12 and bigger.elements == (CUBIC,)
    with pytest.raises(ValueError, match="already in revision"):
        copy.add_revision(add=[CUBIC], base=1)
    with pytest.raises(ValueError, match="is not in the revision"):
        copy.add_revision(remove=[NonlinearElement("quadratic_damping", "x1")])
    with pytest.raises(ValueError, match="not an output of the study"):
        copy.add_revision(add=[NonlinearElement("quadratic_damping", "x9")])
    assert len(copy.revisions) == 4   # failed requests store nothing


def test_save_and_load_round_trip_without_pickle(study, tmp_path):
    folder = study.save(tmp_path / "study")
    assert {p.name for p in folder.iterdir()} == {"study.json", "estimation.npz",
                                                  "validation.npz", "revisions.npz"}
    with np.load(folder / "revisions.npz", allow_pickle=False) as arrays:
        assert all(arrays[k].dtype != object for k in arrays.files)
    loaded = Study.load(folder)
    assert json.dumps(loaded.to_json(), sort_keys=True) == json.dumps(study.to_json(),
                                                                     sort_keys=True)
    np.testing.assert_array_equal(loaded.revisions[1].model.A, study.revisions[1].model.A)
    np.testing.assert_array_equal(loaded.revisions[1].simulated, study.revisions[1].simulated)
    assert loaded.connections == (("x2", "x4"),)


def test_a_model_refined_at_the_internal_rate_keeps_its_rate_when_reloaded(study, tmp_path):
    """A refined model with non-smooth elements lives at a multiple of fs
    (:mod:`fnsi.refinement`); reloaded at the data's rate it would be simulated four times
    too slow."""
    copy = Study.load(study.save(tmp_path / "copy"))
    revision = copy.revisions[1]
    copy.revisions[1] = dataclasses.replace(revision, model=dataclasses.replace(
        revision.model, fs=4 * revision.model.fs))
    loaded = Study.load(copy.save(tmp_path / "fine"))
    assert loaded.revisions[1].model.fs == 4 * study.estimation.fs
    assert loaded.revisions[0].model.fs == study.estimation.fs


def test_revisions_record_the_separability_of_their_elements(study, data):
    assert study.revisions[0].separability == ()
    (cubic,) = study.revisions[1].to_json()["separability"]
    assert cubic["name"] == "polynomial x3" and not cubic["confounded"]
    # a spline beside the cubic at the same connection shares its force
    both = Study.create(*data, SETTINGS, name="both")
    both.add_revision(add=[CUBIC, NonlinearElement("spline", "x3", intervals=9)])
    assert [s["confounded"] for s in both.revisions[1].separability] == [True, True]


def test_loaded_study_can_be_diagnosed_and_extended(study, tmp_path):
    loaded = Study.load(study.save(tmp_path / "again"))
    diagnosis = loaded.diagnose(settings=DiagnosisSettings(validated_candidates=1,
                                                           curve_locations=0))
    assert not diagnosis.found       # revision 1 already holds the hidden effect
    # never proposed again: the law it holds at x3, whatever its parameters
    assert not any(p.location.dof == "x3" and p.location.ref is None
                   and p.element.kind == "polynomial" and p.element.exponent == 3.0
                   for p in diagnosis.proposals)
    # the revision is at the floor: the summary may say that nothing is missing
    assert diagnosis.nrmse_before_percent < 3 * diagnosis.noise_floor_percent
    assert "no missing effect is detected" in diagnosis.summary
    figures = diagnosis_figures(diagnosis)
    assert {"screening.png", "candidates.png"} <= set(figures)
    assert all(png.startswith(PNG) for png in figures.values())


def test_elements_are_labelled_by_their_law():
    quadratic = NonlinearElement("polynomial", "x2", "x3", exponent=2.0, signed=False)
    stop = NonlinearElement("clearance", "x4", gap_positive=1e-3, side="positive")
    assert [law_name(e) for e in (CUBIC, quadratic, stop)] == [
        "cubic spring x3", "quadratic spring x2-x3", "one-sided stop x4"]


def test_json_is_strict(study):
    text = json.dumps(study.to_json(), allow_nan=False)
    assert json.loads(text)["revisions"][1]["elements"] == [CUBIC.to_json()]
    spectra = study.to_json(spectra=True)["revisions"][0]["validation"]["spectra"]
    lines = len(spectra["frequency_hz"])
    assert len(spectra["error_db"]) == len(spectra["excited"]) == lines
    assert len(spectra["error_db"][0]) == 5


def test_bad_inputs_say_what_to_change(data, tmp_path):
    estimation, validation = data
    with pytest.raises(ValueError, match="differ in output_names"):
        Study(estimation, validation.select(outputs=("x1", "x2")), SETTINGS)
    with pytest.raises(ValueError, match="must join two different outputs"):
        Study(estimation, validation, SETTINGS, connections=[("x1", "x7")])
    with pytest.raises(ValueError, match=r"holds no study\.json"):
        Study.load(tmp_path)
    with pytest.raises(ValueError, match="no revision yet"):
        Study(estimation, validation, SETTINGS).add_revision(order=8)
    assert math.isfinite(Study(estimation, validation, SETTINGS).noise_floor_percent)


def _unstable_revision_settings():
    """The README's record and stop at order 14, whose poles are unstable (|z| = 1.0003-1.0004)."""
    from fnsi.identification import IdentificationSettings
    from fnsi.smallsat import simulate_preset

    record, _ = simulate_preset("single", periods=3, samples_per_period=2500, seed=1)
    stop = NonlinearElement.from_json(
        {"kind": "clearance", "dof": "NC2w_Z", "ref": "NC2b_Z", "gap": 1.5})
    return record, IdentificationSettings(outputs=("NC2w_Z", "NC2b_Z", "W_Z"),
                                          band=(5.0, 50.0), block_rows=20, max_order=20,
                                          order=14, elements=(stop,))


def test_an_unstable_revision_is_repaired_and_the_table_says_how(tmp_path):
    record, settings = _unstable_revision_settings()
    study = Study.create(record, record, settings)
    revision = study.revisions[0]
    # repaired, not dropped: the poles reflected inside the unit circle ...
    assert np.max(np.abs(np.linalg.eigvals(revision.model.A))) < 1.0
    assert revision.repairs and "reflected inside the unit circle" in revision.repairs[0]
    # ... and the stiff contact loop reaches its periodic state by the simulation's
    # corrections (it diverged within 100 periods without them): an error, not a failure,
    # though far from the 0.30 % floor (5.1 % measured: this order misses modes)
    assert revision.failure is None and 0.3 < revision.nrmse_percent < 20
    table = study.history_table().splitlines()
    assert table[2].strip() == f"repaired: {revision.repairs[0]}"
    assert study.history()[0]["repairs"] == list(revision.repairs)
    reloaded = Study.load(study.save(tmp_path / "repaired"))
    assert reloaded.revisions[0].repairs == revision.repairs


def test_a_repaired_revision_that_diverges_fails_and_the_table_says_both(monkeypatch):
    from fnsi.simulation import SimulationDivergedError

    def diverges(*args, **kwargs):
        raise SimulationDivergedError("the simulated response diverged")

    monkeypatch.setattr("fnsi.study.compare_identified", diverges)
    record, settings = _unstable_revision_settings()
    revision = (study := Study.create(record, record, settings)).revisions[0]
    assert "diverged" in revision.failure and "were reflected inside" in revision.failure
    table = study.history_table().splitlines()
    assert "failed" in table[1] and table[2].strip() == f"failed: {revision.failure}"
    assert table[3].strip() == f"repaired: {revision.repairs[0]}"


def test_revisions_give_their_errors_modes_and_coefficients_with_standard_deviations(study):
    linear, cubic = study.revisions
    for revision in (linear, cubic):
        # the noise moves the NRMSE by a fraction of itself (the MC check of the
        # jackknife is tests/fnsi/test_uncertainty.py)
        assert 0 < revision.nrmse_std_percent < revision.nrmse_percent
    assert study.history()[1]["nrmse_std_percent"] == cubic.nrmse_std_percent
    document = study.to_json()["revisions"][1]
    modal = document["modal"]
    assert len(modal["frequency_hz_std"]) == len(modal["frequency_hz"]) > 0
    assert all(0 < s < 0.01 * f for s, f in zip(modal["frequency_hz_std"],
                                                 modal["frequency_hz"], strict=True))
    (coefficient,) = document["coefficients"]
    assert 0 < coefficient["mean_real_std"] < 0.1 * abs(coefficient["mean_real"])


def test_a_study_without_driving_point_warns_once_how_to_give_it(data):
    renamed = [dataclasses.replace(m, input_names=("shaker",)) for m in data]
    settings = dataclasses.replace(SETTINGS, driving_points=(), uncertainty=False)
    study = Study(*renamed, settings)
    assert study.warnings == []                  # no element yet: nothing to scale
    study = Study.create(*renamed, dataclasses.replace(settings, elements=(CUBIC,)))
    (warning,) = study.warnings
    assert "input 'shaker' names no output" in warning and "driving_points" in warning
    assert study.history_table().splitlines()[-2] == f"warning: {warning}"
    assert study.to_json()["warnings"] == [warning]


def test_an_automatic_study_chooses_each_revisions_order_by_simulation(data):
    # order "auto": revision 0 and the revision adding the true cubic spring each take
    # the order that simulates the estimation data best, the added one searched again
    # (the default order of a new revision is the one its base asked for)
    auto = Study.create(*data, dataclasses.replace(SETTINGS, order="auto"))
    cubic = auto.add_revision(add=[CUBIC])
    assert auto.revisions[0].order == "auto" and cubic.order == "auto"
    assert cubic.note == "add cubic spring x3"
    # the chain's five modes: every order chosen holds at least their ten states
    assert auto.revisions[0].identified_order >= 10 and cubic.identified_order >= 10
    # with the true element the model reaches the floor (measured 1.0-1.3 x)
    assert cubic.nrmse_percent < 1.5 * auto.noise_floor_percent
    assert cubic.nrmse_percent < auto.revisions[0].nrmse_percent / 10


def test_a_model_that_cannot_run_the_validation_input_takes_the_next_order(data,
                                                                           monkeypatch):
    """Seed 37 case 3 of the hidden benchmark: the true clearance's model at its
    automatic order diverged on the validation input, and the candidate was never
    judged, while lower orders ran it. Here the chosen order's model is made to diverge:
    the next best order at simulating the estimation record is taken, and said."""
    from fnsi import study as study_module
    from fnsi.simulation import SimulationDivergedError

    auto = Study.create(*data, dataclasses.replace(SETTINGS, order="auto"))
    chosen = auto.evaluate([CUBIC], "auto", trial=True)
    search = chosen.identification.simulation_order
    compare = study_module.compare_identified

    def diverges_at_the_chosen_order(result, *args, **kwargs):
        if result.order == chosen.order:
            raise SimulationDivergedError("the simulated response diverged")
        return compare(result, *args, **kwargs)

    monkeypatch.setattr(study_module, "compare_identified", diverges_at_the_chosen_order)
    taken = auto.evaluate([CUBIC], "auto", trial=True)
    ((_, best_other),) = sorted((e, o) for o, e in search.errors.items()
                                if o != chosen.order and math.isfinite(e))[:1]
    assert taken.failure is None and taken.order == best_other != chosen.order
    assert taken.repairs[0].startswith(f"order {best_other} taken, the next best")
    assert f"order {chosen.order}'s model could not run" in taken.repairs[0]
    # an order the user set is never changed: it fails and says why
    fixed = auto.evaluate([CUBIC], chosen.order, trial=True)
    assert fixed.simulated is None and "diverged" in fixed.failure


CUBIC_X4_X3 = NonlinearElement("polynomial", "x4", "x3", exponent=3.0, coefficients=(4.153e9,))


def chain_records(quantity: str, noise_percent: float) -> list:
    """Estimation and validation records of a 5-DOF chain with a cubic spring between x4
    and x3, driven at x1 in 3-50 Hz (its five modes: 8.2-35 Hz), two kept periods."""
    from fnsi.acquisition import acquire
    from fnsi.excitation import Excitation, multisine
    from fnsi.structure import StructuralModel

    names, fs, band = ("x1", "x2", "x3", "x4", "x5"), 256.0, (3.0, 50.0)
    m = np.diag([0.8924, 0.9477, 1.7213, 0.6379, 1.4002])                   # kg
    springs = np.array([15928.4, 7818.5, 5827.2, 9124.5, 14861.5, 13434.0])  # N/m, grounded
    k = np.diag(springs[:-1] + springs[1:]) - np.diag(springs[1:-1], 1) - np.diag(
        springs[1:-1], -1)
    c = 1.21195 * m + 1.06846e-4 * k                                       # Rayleigh
    model = StructuralModel(m, c, k, names, (CUBIC_X4_X3,))
    return [acquire(model, Excitation.at_dof(multisine(1024, fs, band, 10.0, seed=20 + r),
                                             fs, "x1"),
                    fs=fs, fs_int=8 * fs, periods=3, quantity=quantity,
                    noise_percent=noise_percent, discard_periods=1, seed=19 + r)[0]
            for r in (1, 2)]


@pytest.mark.parametrize("quantity", ["velocity", "acceleration"])
def test_a_cubic_spring_measured_in_velocity_or_acceleration_reaches_the_floor(quantity):
    """Integrated, the sensor noise grows under the band (dropped from the bases' motion
    unless it stands out) and at the band's lower edge (weighted by the automatic
    weighting). In acceleration, with the lines under the band kept at twice their noise
    and no weighting, FNSI took a pole at 2-3 Hz for the 35 Hz mode and identified
    2.5e7 for 4.15e9 N/m^3: the revision stopped at 10.8 % for a 0.73 % floor."""
    from fnsi.identification import IdentificationSettings

    study = Study.create(*chain_records(quantity, 0.5), IdentificationSettings(band=(3.0, 50.0)))
    revision = study.add_revision(add=[dataclasses.replace(CUBIC_X4_X3, coefficients=None)])
    # measured 1.06 (velocity) and 1.10 (acceleration) times the floor
    assert revision.nrmse_percent < 1.5 * study.noise_floor_percent


def test_a_revision_that_refines_badly_at_its_simulated_order_is_refined_at_others():
    """Noisy bases (a chain measured in velocity with 2 % noise, unweighted) bias FNSI,
    and the order that simulates the estimation record best is one whose extra states
    make up for it: there the model cannot be refined (order 54, 20.5 %). Refined at the
    order of the revision without the element (8) it validates at 8.7 %; at the orders
    above the automatic one at 2.7-4.1 % (the refined estimation errors 2.2-2.3 %), and
    the lowest of those within the search's tolerance of the best is kept."""
    from fnsi.identification import IdentificationSettings

    study = Study.create(*chain_records("velocity", 2.0),
                         IdentificationSettings(band=(3.0, 50.0), weighting=False))
    revision = study.add_revision(add=[dataclasses.replace(CUBIC_X4_X3, coefficients=None)])
    # measured 2.72 % at order 56 against the linear revision's 17.2 % (floor 2.5 %;
    # 4.09 % when every rung took 60 refinement steps, fnsi.refinement.MAX_REFINEMENT_WORK);
    # at order 8, the best before the orders above were tried, 8.7 %
    assert revision.nrmse_percent < 0.35 * study.revisions[0].nrmse_percent
    assert revision.identified_order > 54
    assert "refined at order" in revision.repairs[-1]


def _ladder_evaluation(order: int, estimation: float, validation: float):
    """An evaluation as the order ladder reads it: the order, the refined estimation
    error [%] and the validation error [%]."""
    from types import SimpleNamespace

    from fnsi.study import Evaluation

    identification = SimpleNamespace(
        order=order, refinement=SimpleNamespace(final_percent=estimation),
        simulation_order=SimpleNamespace(noise_floor_percent=0.1, order=order, errors={}),
        settings=SimpleNamespace(harmonic_band=True))
    return Evaluation((CUBIC_X4_X3,), identification, None, None, None, validation)


def test_the_order_ladder_keeps_an_order_only_if_it_validates_better():
    """The ladder chooses its order by the estimation record; a model that fits it
    better but validates worse than the automatic order's is not kept (seed 27 case 11
    of the hidden benchmark: order 64 refined, 1.16 % on the estimation record and
    5.52 % on the validation one, against FNSI's order 60 at 2.5 %)."""
    rungs = {12: _ladder_evaluation(12, 1.42, 2.42), 62: _ladder_evaluation(62, math.inf, 9.0),
             64: _ladder_evaluation(64, 1.16, 5.52), 66: _ladder_evaluation(66, 1.5, 2.6)}
    ladder = types.SimpleNamespace(evaluate=lambda elements, order, *a, **k: rungs[order])
    automatic = _ladder_evaluation(60, 2.0, 10.1)
    best = _ladder_evaluation(60, 2.0, 2.5)
    assert Study._refined_order(ladder, automatic, best, None, 12) is best
    # the same ladder where the chosen order validates better: kept, and said so
    rungs[64] = _ladder_evaluation(64, 1.16, 1.9)
    chosen = Study._refined_order(ladder, automatic, best, None, 12)
    assert chosen.order == 64 and "refined at order 64" in chosen.repairs[-1]


def test_noise_free_records_are_studied_without_a_noise_floor_to_divide_by():
    """Exactly periodic records without noise have a zero floor: every model then misses
    it and is refined, and the repair's words quoted the miss as a multiple of the floor
    (a ZeroDivisionError failed Study.create on a noise-free case of the generalisation
    benchmark)."""
    from fnsi.identification import IdentificationSettings

    def periodic(record):   # its last period repeated: no transient, no noise
        last = slice(-record.period_length, None)
        return dataclasses.replace(
            record, u=np.tile(record.u[:, last], (1, record.periods, 1)),
            y=np.tile(record.y[:, last], (1, record.periods, 1)))

    study = Study.create(*map(periodic, chain_records("displacement", 0.0)),
                         IdentificationSettings(band=(3.0, 50.0)))
    # at the chain's order: the automatic one would climb the refinement's order ladder
    # (every model misses a zero floor), which costs a minute and tests nothing here
    revision = study.add_revision(add=[CUBIC_X4_X3], order=10)
    assert study.noise_floor_percent == 0.0
    # three modes for five: the refinement improves it, and says so without a ratio
    refined = study.better_refined(study.evaluate((), 6))
    assert any("missed the noise-free validation data" in w for w in refined.repairs)
    # noise free, the true element leaves little (18 % -> 0.03 % measured): a tenth is
    # far from both
    assert revision.nrmse_percent < 0.1 * study.revisions[0].nrmse_percent


def test_a_model_is_refined_from_a_fit_on_the_lines_it_was_fitted_on(monkeypatch):
    """Refinement re-identifies the model at its order: from the band's fit alone, a
    model fitted on the band with its harmonics and the lines under it would lose the
    modes the forces drive there, which refinement does not find again (a cubic spring
    of the hidden benchmark, seed 22 case 16: 6.3 % refined from the band's fit, 0.90 %
    from the wider one, floor 0.85 %)."""
    from fnsi.identification import IdentificationSettings

    study = Study.create(*chain_records("displacement", 0.5),
                         IdentificationSettings(band=(3.0, 50.0)))
    element = dataclasses.replace(CUBIC_X4_X3, coefficients=None)
    asked = []
    evaluate = Study.evaluate

    def spy(self, *args, **kwargs):
        asked.append(kwargs.get("harmonic_band", False))
        return evaluate(self, *args, **kwargs)

    for wide in (False, True):
        fitted = study.evaluate([element], 10, trial=True, harmonic_band=wide)
        assert fitted.identification.settings.harmonic_band is wide
        monkeypatch.setattr(Study, "evaluate", spy)
        study.better_refined(fitted, trial=True, iterations=2)
        monkeypatch.setattr(Study, "evaluate", evaluate)
        assert asked.pop() is wide


def _shaped_evaluation(element: NonlinearElement, model_element: NonlinearElement,
                       validation: float, refined: bool = True):
    """An evaluation as the second identification reads it: the elements asked for, the
    model's (refined) elements and the validation error [%]."""
    from fnsi.study import Evaluation

    identification = types.SimpleNamespace(
        refinement=types.SimpleNamespace() if refined else None,
        model=types.SimpleNamespace(elements=(model_element,)))
    return Evaluation((element,), identification, None, None, None, validation)


@pytest.mark.parametrize(("first", "second", "kept"), [
    (1.91, 1.42, "again"),     # better with the refined gaps: kept, and said so
    (1.91, 2.50, "first"),     # worse: the first is kept
    (0.40, 0.30, "first"),     # the first within twice the floor (0.254 %): no second try
])
def test_a_revision_whose_refinement_moved_its_gaps_is_identified_again_with_them(
        first, second, kept):
    """Seed 35 case 0 of the hidden benchmark: the proposed gaps chose order 18 and
    refined to 1.91 %, the gaps moving within 1.2 % of the truth; identified again with
    the refined gaps, 1.54 % (the true gaps: 1.42 %). The errors here stand for those."""
    proposed = NonlinearElement("clearance", "x5", "x6", gap_negative=4.48e-4,
                                gap_positive=4.32e-4)
    refined = dataclasses.replace(proposed, gap_negative=4.24e-4, gap_positive=4.82e-4)
    evaluations = {(proposed,): _shaped_evaluation(
                       proposed, dataclasses.replace(refined, coefficients=(3.1e4,)), first),
                   (refined,): _shaped_evaluation(refined, refined, second)}
    asked = []

    def evaluate(elements, order, progress=None, **options):
        asked.append(tuple(elements))
        return evaluations[tuple(elements)]

    study = types.SimpleNamespace(evaluate=evaluate,
                                  _refined_if_needed=lambda e, *a, **k: e,
                                  misses_floor=lambda error: error > 2 * 0.254)
    result = Study.kept_evaluation(study, [proposed], "auto", order_near=18)
    if kept == "again":
        assert asked == [(proposed,), (refined,)]
        assert result.elements == (refined,) and result.nrmse_percent == second
        assert "identified again with the shapes" in result.repairs[-1]
    else:
        assert asked[0] == (proposed,) and result is evaluations[(proposed,)]
        assert len(asked) == (2 if first > 2 * 0.254 else 1)
    # a model whose refinement kept its shapes, or that was not refined, is not redone
    asked.clear()
    evaluations[(proposed,)] = _shaped_evaluation(proposed, proposed, first)
    Study.kept_evaluation(study, [proposed], "auto", order_near=18)
    evaluations[(proposed,)] = _shaped_evaluation(proposed, refined, first, refined=False)
    Study.kept_evaluation(study, [proposed], "auto", order_near=18)
    assert asked == [(proposed,), (proposed,)]


def test_an_element_is_removed_as_it_was_added_when_the_revision_refined_its_gaps():
    """A revision identified again with its refined gaps holds those; the clearance the
    user added (the diagnosis's proposal) still names it, when it is the only one of its
    law at that place."""
    proposed = NonlinearElement("clearance", "x5", "x6", gap_negative=4.48e-4,
                                gap_positive=4.32e-4)
    refined = dataclasses.replace(proposed, gap_negative=4.24e-4, gap_positive=4.82e-4)
    cubic = NonlinearElement("polynomial", "x5", "x6", exponent=3.0)
    assert _find([cubic, refined], proposed.to_json()) == 1
    assert _find([cubic, refined], refined) == 1
    with pytest.raises(ValueError, match="is not in the revision"):   # two alike: ambiguous
        _find([refined, dataclasses.replace(refined, gap_positive=5e-4)], proposed)
    with pytest.raises(ValueError, match="is not in the revision"):   # another place
        _find([refined], dataclasses.replace(proposed, ref="x4"))

