"""Simulate, identify and fetch every artefact over real HTTP, once with the embedded
runner (fnsi-service alone) and once with a real fnsi-worker behind Redis."""

from __future__ import annotations

import io
import json
import time

import numpy as np
import pytest

from fnsi.statespace import StateSpaceModel
from service.schemas.results import IdentificationJobResult
from tests.service.servers import wait_for_job, wait_for_progress
from tests.service.test_simulations import REQUEST as MODEL_SIMULATION

PNG = b"\x89PNG\r\n\x1a\n"
TRUE_CUBIC = 1.0e8            # N/m^3, MODEL_SIMULATION's element
EXACT_HZ = np.sqrt([1.0e4, 3.0e4]) / (2 * np.pi)
# block rows "auto": 11, twice the rows order 10 needs with two outputs; with i = 10 a
# noise pole at 16.8 Hz at order 6 moves the 15.9 Hz mode's damping from 0.94 to 0.77 %,
# so order 4 is not confirmed and the mode is dropped
IDENTIFICATION = {
    "band": [5.0, 40.0], "block_rows": "auto", "max_order": 10,
    "elements": [{"kind": "polynomial", "dof": "x1", "exponent": 3}],
    "driving_points": [["F_x1", "x1"]],
}


@pytest.fixture(scope="module")
def datasets(stack) -> tuple[str, str]:
    """Estimation and validation data simulated in one batch."""
    with stack.client() as client:
        jobs = [{"kind": "simulation", "request": {**MODEL_SIMULATION, "periods": 4,
                                                   "excitation": {**MODEL_SIMULATION["excitation"],
                                                                  "seed": seed}}}
                for seed in (4, 5)]
        batch = client.post("/v1/batches", json={"jobs": jobs})
        assert batch.status_code == 202, batch.text
        simulated = [wait_for_job(client, job_id) for job_id in batch.json()["job_ids"]]
        assert [j["state"] for j in simulated] == ["succeeded"] * 2, simulated
        estimation, validation = (j["result"]["dataset_id"] for j in simulated)
        return estimation, validation


def _identify(stack, datasets: tuple[str, str], **options) -> dict:
    estimation, validation = datasets
    with stack.client() as client:
        submitted = client.post("/v1/identifications", json={
            **IDENTIFICATION, **options, "dataset_id": estimation,
            "validation_dataset_id": validation})
        assert submitted.status_code == 202, submitted.text
        job = wait_for_job(client, submitted.json()["id"])
        assert job["state"] == "succeeded", job
        return job


@pytest.fixture(scope="module")
def identified(stack, datasets):
    """One identification of the simulated data."""
    return _identify(stack, datasets)


def test_refined_identification_simulates_closer(stack, datasets, identified):
    refined = _identify(stack, datasets, refine=True)["result"]
    summary = refined["refinement"]
    assert summary["final_percent"] < summary["initial_percent"]
    assert summary["iterations"] >= 1 and "refinement" in refined["timings_s"]
    errors = [r["errors"]["validation"]["overall_nrmse_percent"]
              for r in (identified["result"], refined)]
    assert errors[1] < errors[0]
    # modes and coefficients are FNSI's, as without refinement
    assert refined["coefficients"] == identified["result"]["coefficients"]
    assert "refinement" not in identified["result"] or identified["result"]["refinement"] is None


def test_frequency_warping_reaches_the_library(stack, datasets):
    result = _identify(stack, datasets, frequency_warping=True)["result"]
    assert result["settings"]["frequency_warping"] is True
    (coefficient,) = result["coefficients"]
    np.testing.assert_allclose(coefficient["mean_real"], TRUE_CUBIC, rtol=0.03)


def test_offsets_are_reported_and_removed_on_request(stack, datasets, identified):
    removed = _identify(stack, datasets, remove_offsets=True)["result"]
    assert removed["settings"]["remove_offsets"] is True
    for result, flag in ((identified["result"], False), (removed, True)):
        assert result["offsets"]["removed"] is flag
        for kind in ("estimation", "validation"):
            offsets = result["errors"][kind]["offsets"]
            assert {"inputs", "outputs"} <= set(offsets)
            assert all("unit" in c and "offset" in c for c in offsets["outputs"])
    # the OpenAPI schema types them: the documented model reads every field back
    typed = IdentificationJobResult.model_validate(removed)
    assert typed.offsets.removed is True and typed.settings.remove_offsets is True
    assert [c.channel for c in typed.errors.validation.offsets.outputs] == ["x1", "x2"]
    # simulated sensors read the true motion: its mean is tiny, so removing it changes
    # the cubic by far less than the 3 % the truth test allows
    np.testing.assert_allclose(removed["coefficients"][0]["mean_real"],
                               identified["result"]["coefficients"][0]["mean_real"], rtol=0.01)


def test_identification_result_matches_the_simulated_truth(identified):
    result = identified["result"]
    assert result["order"] == 4
    # 1 % output noise, 3 kept periods of 1000 samples: frequencies within 0.5 %
    # (the cubic spring shifts them by ~0.1 % at this level), coefficient within 3 %.
    np.testing.assert_allclose([m["frequency_hz"] for m in result["modes"]], EXACT_HZ,
                               rtol=5e-3)
    (coefficient,) = result["coefficients"]
    assert coefficient["identifiable"]
    np.testing.assert_allclose(coefficient["mean_real"], TRUE_CUBIC, rtol=0.03)
    for kind in ("estimation", "validation"):
        errors = result["errors"][kind]
        assert [c["output"] for c in errors["channels"]] == ["x1", "x2"]
        # a correct model leaves an error at the noise level, a few % of the response
        assert errors["overall_nrmse_percent"] < 10
    assert set(result["timings_s"]) >= {"decomposition", "physical"}
    assert identified["progress"] == 1.0


def test_every_artefact_downloads(stack, identified):
    with stack.client() as client:
        listing = client.get(f"/v1/jobs/{identified['id']}/artefacts").json()
        names = {a["name"] for a in listing}
        assert names == {"stabilisation.png", "frf.png", "coefficients.png", "stiffness.png",
                         "macx.png", "errors.png", "result.json", "model.npz", "report.html",
                         "modes.uff", "result.mat"}
        for artefact in listing:
            response = client.get(artefact["url"])
            assert response.status_code == 200
            assert response.headers["content-type"].startswith(artefact["media_type"])
            assert len(response.content) == artefact["size_bytes"]
            if artefact["name"].endswith(".png"):
                assert response.content.startswith(PNG)
        full = client.get(f"/v1/jobs/{identified['id']}/artefacts/result.json").json()
        model = StateSpaceModel.from_npz(io.BytesIO(
            client.get(f"/v1/jobs/{identified['id']}/artefacts/model.npz").content))
        np.testing.assert_array_equal(model.A, np.array(full["model"]["A"]))
        assert model.elements[0].to_json()["exponent"] == 3.0
        assert full["stabilisation"] is not None


def test_a_running_job_cancels_within_seconds(stack):
    long = {**MODEL_SIMULATION, "periods": 1000, "fs_int": 20000.0}
    with stack.client() as client:
        job = client.post("/v1/simulations", json=long).json()
        wait_for_progress(client, job["id"], 0.01)
        asked = time.monotonic()
        assert client.delete(f"/v1/jobs/{job['id']}").status_code == 202
        final = wait_for_job(client, job["id"], timeout=30)
        assert final["state"] == "cancelled"
        assert time.monotonic() - asked < 5
        assert final["result"] is None


def test_health_reports_the_execution_mode(stack):
    with stack.client() as client:
        body = client.get("/health").json()
    assert body["queue"] == ("celery" if "FNSI_BROKER_URL" in stack.env else "embedded")
    assert json.dumps(body)


def test_smallsat_preset_simulates_and_identifies_the_clearance(stack):
    """The paper's single-input case on a short record (docs/design.md workload single-3)."""
    with stack.client() as client:
        simulation = client.post("/v1/simulations", json={
            "preset": "single", "periods": 3, "samples_per_period": 2500, "seed": 1,
            "outputs": ["NC2w_Z", "NC2b_Z", "W_Z"]}).json()
        simulated = wait_for_job(client, simulation["id"])
        assert simulated["state"] == "succeeded", simulated
        truth = client.get(f"/v1/jobs/{simulation['id']}/artefacts/truth.json").json()
        assert truth["exceedances"]["clearance NC2w_Z-NC2b_Z"] > 0  # the stop is hit
        submitted = client.post("/v1/identifications", json={
            "dataset_id": simulated["result"]["dataset_id"], "band": [5.0, 50.0],
            "block_rows": 20, "max_order": 20,
            "elements": [{"kind": "clearance", "dof": "NC2w_Z", "ref": "NC2b_Z",
                          "gap": 1.5}]}).json()
        job = wait_for_job(client, submitted["id"])
        assert job["state"] == "succeeded", job
        (coefficient,) = job["result"]["coefficients"]
        # Table 2: added stiffness 100 beyond the gap. Two kept periods of 2500 samples
        # (46 lines) give a few % (3.6 % with seed 1); the paper's 8 x 30,000 gives < 1 %.
        np.testing.assert_allclose(coefficient["mean_real"], 100.0, rtol=0.1)
        (separation,) = job["result"]["separability"]
        assert separation["name"] == "clearance NC2w_Z-NC2b_Z"
        assert not separation["confounded"] and separation["concern"] is None
        names = {a["name"] for a in client.get(f"/v1/jobs/{job['id']}/artefacts").json()}
        # the README's session: the automatic order's model simulates (orders 10-20 of
        # this record have unstable poles outside the kept modes), and whatever the
        # result warns of, the job shows
        assert {"stabilisation.png", "frf.png", "coefficients.png", "stiffness.png",
                "macx.png", "errors.png", "result.json", "model.npz"} <= names
        assert job["result"]["errors"]["estimation"]["overall_nrmse_percent"] is not None
        assert job["warnings"] == job["result"]["warnings"]
        png = client.get(f"/v1/jobs/{job['id']}/artefacts/stiffness.png")
        assert png.content.startswith(PNG)
