"""Every returned model can be simulated, or the result says loudly that it cannot.

The record is the README's HTTP session: the SmallSat single test, 3 periods of 2500
samples, seed 1, three outputs, i = 20, diagram up to order 20. Its orders 10 to 20 have
unstable poles outside the kept modes (|z| from 1.0005 to 1.0018).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fnsi.identification import IdentificationSettings, identify
from fnsi.nonlinear import NonlinearElement
from fnsi.report import identification_report
from fnsi.smallsat import simulate_preset
from fnsi.validation import compare


@pytest.fixture(scope="module")
def readme_record():
    measurement, _ = simulate_preset("single", periods=3, samples_per_period=2500, seed=1)
    return measurement


def _settings(**changes) -> IdentificationSettings:
    stop = NonlinearElement.from_json(
        {"kind": "clearance", "dof": "NC2w_Z", "ref": "NC2b_Z", "gap": 1.5})
    return IdentificationSettings(outputs=("NC2w_Z", "NC2b_Z", "W_Z"), band=(5.0, 50.0),
                                  block_rows=20, max_order=20, elements=(stop,), **changes)


def _radius(A: np.ndarray) -> float:
    return float(np.max(np.abs(np.linalg.eigvals(A))))


def test_automatic_order_returns_a_model_that_simulates(readme_record):
    result = identify(readme_record, _settings())
    diagram = result.stabilisation
    assert _radius(result.model.A) < 1.0
    if result.order not in diagram.simulable_orders():
        # reflected: the note names the poles, the kept modes are those of the diagram
        assert "reflected inside the unit circle" in result.warnings[0]
    assert len(result.warnings) <= 1
    np.testing.assert_array_equal(
        result.modal.frequencies,
        diagram.at(result.order).modes.frequencies[diagram.physical(result.order)])
    errors = compare(result.model, readme_record, discard_periods=1, band_high=50.0).errors
    # a stable linear part and the true stop: the simulation does not diverge
    assert np.all(np.isfinite(errors.nrmse_percent))


def test_explicit_unstable_order_is_returned_with_a_warning(readme_record):
    settings = _settings(order=14)
    result = identify(readme_record, settings)
    assert _radius(result.model.A) > 1.0   # 1.0018 on this record: every pole returned
    (warning,) = result.warnings
    assert "unstable" in warning and "cannot be simulated" in warning
    stable = result.stabilisation.simulable_orders()
    assert stable and str(list(stable)) in warning
    report = identification_report(result, settings, readme_record)
    assert report.document["warnings"] == [warning]
    assert "unstable" in report.document["errors"]["estimation"]["failure"]
    assert "errors.png" not in report.artefacts


def test_report_warns_when_a_stable_model_cannot_be_simulated(readme_record):
    settings = _settings()
    result = identify(readme_record, settings)
    # a stop a thousand times stiffer: the linear part is stable, the simulation is not
    model = result.model
    B = model.B.copy()
    B[:, model.n_inputs:] *= 1e3
    broken = dataclasses.replace(result, model=dataclasses.replace(model, B=B), warnings=())
    report = identification_report(broken, settings, readme_record)
    failure = report.document["errors"]["estimation"]["failure"]
    (warning,) = report.document["warnings"]
    assert failure in warning and "errors.png is absent" in warning
    assert "errors.png" not in report.artefacts
