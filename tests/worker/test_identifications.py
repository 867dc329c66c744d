"""Identification jobs never succeed without a result: a job whose model or errors are
NaN, or whose automatic order keeps no mode, fails with a reason that says what to change."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fnsi.identification import IdentificationSettings, identify
from fnsi.measurement import Measurement
from fnsi.report import identification_report
from service.settings import Settings
from service.store import JobState, Store
from tests.service import formats
from worker.identifications import nothing_identified
from worker.runner import run_job
from worker.tasks import TASKS

REC = formats.make_record()  # fs 1000 Hz, 4 periods x 500 samples, force -> NC2w_Z, NC2b_Z
# An explicit order: the record's outputs are sines unrelated to the force, in which the
# automatic order finds no plateau; order 6 returns a model with two modes in band. The
# sines are undamped, so its largest poles sit at |z| = 1 +- 2e-5, on either side by chance
# (1.000016 from the orthonormal band basis, 0.9985 from the powers z^p).
REQUEST = {"validation_dataset_id": None, "inputs": None, "outputs": None,
           "band": [5.0, 100.0], "block_rows": 10, "order": 6, "max_order": 10,
           "line_set": "all", "discard_periods": 1, "weighting": False,
           "driving_points": [], "elements": []}


def record(scale: float) -> Measurement:
    return Measurement.from_arrays(scale * REC.u, scale * REC.y, REC.fs,
                                   input_names=REC.input_names,
                                   output_names=REC.output_names, periods=REC.periods)


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # the overflow this test is about
# its figures draw what is finite (an overflowed FRF curve cannot be log-scaled)
@pytest.mark.filterwarnings("error::UserWarning")
@pytest.mark.parametrize(("scale", "state"), [(1.0, JobState.SUCCEEDED),
                                              (1e200, JobState.FAILED)],
                         ids=["control", "values-near-1e200"])
def test_a_job_whose_errors_are_nan_on_every_channel_fails_saying_why(tmp_path, scale, state):
    """The issue's record with values near 1e200: FNSI's modes are finite, but the errors'
    squares overflow, so every NRMSE is NaN; the same record at its own scale succeeds."""
    settings = Settings(data_dir=tmp_path, broker_url=None)
    store = Store(settings.data_dir)
    dataset = store.put_measurement(record(scale), owner="me", name="rec")
    job = store.create_job("me", "identification", {**REQUEST, "dataset_id": dataset.id})
    run_job(job.id, settings, TASKS)
    done = store.get_job(job.id)
    assert done.state == state, done.error
    if state == JobState.FAILED:
        assert "errors are NaN on every channel" in done.error
        peak = scale * max(np.abs(REC.u).max(), np.abs(REC.y).max())
        assert f"values reach {peak:.3g}" in done.error and "rescale" in done.error
        assert "stabilisation.png" in [name for name, _ in store.list_artefacts(job.id)]
    else:  # errors, or the reason there are none, but never NaN: the scale was the fault
        errors = done.result["errors"]["estimation"]
        assert (errors.get("overall_nrmse_percent") or 0) > 0 or "unstable" in errors["failure"]
        assert "NaN" not in str(errors)


@pytest.fixture(scope="module")
def identified():
    settings = IdentificationSettings(band=(5.0, 100.0), block_rows=10, order=6, max_order=10)
    result = identify(record(1.0), settings)
    assert result.modal.n_modes > 0
    return result, identification_report(result, settings, record(1.0)).document


@pytest.mark.parametrize(("order", "fails"), [("auto", True), (6, False)])
def test_no_mode_kept_fails_under_the_automatic_order_only(identified, order, fails):
    """Under order "auto" an empty modal table means no confirmed mode: nothing was
    found. An explicit order returns the model asked for, with or without modes in band."""
    result, document = identified
    empty = dataclasses.replace(result, modal=result.modal.subset(
        np.zeros(result.modal.n_modes, dtype=bool)))
    reason = nothing_identified({**REQUEST, "order": order}, empty, document, 1.0)
    if fails:
        assert reason.startswith("no mode found in 5-100 Hz at orders up to 10")
        assert "give it as order" in reason
    else:
        assert reason is None
    assert nothing_identified({**REQUEST, "order": order}, result, document, 1.0) is None


def test_a_model_with_nan_entries_fails(identified):
    result, document = identified
    broken = dataclasses.replace(result, model=dataclasses.replace(
        result.model, A=np.full_like(result.model.A, np.nan)))
    reason = nothing_identified(REQUEST, broken, document, 3.0)
    assert reason.startswith("the identified model holds NaN or infinite numbers")
