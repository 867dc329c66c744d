"""Generic-model simulations through the API: the result is a dataset plus its truth."""

from __future__ import annotations

import time

import numpy as np

M = [[1.0, 0.0], [0.0, 1.0]]
K = [[2.0e4, -1.0e4], [-1.0e4, 2.0e4]]
C = [[2.0, 0.0], [0.0, 2.0]]

REQUEST = {
    "model": {"M": M, "C": C, "K": K, "dof_names": ["x1", "x2"],
              "elements": [{"kind": "polynomial", "dof": "x1", "exponent": 3,
                            "coefficients": [1.0e8]}]},
    "excitation": {"band": [5.0, 40.0], "samples_per_period": 1000, "seed": 4,
                   "inputs": [{"direction": {"x1": 1.0}, "rms": 5.0}]},
    "fs": 500.0, "fs_int": 4000.0, "periods": 3, "discard_periods": 1, "noise_percent": 1.0,
}


def wait(client, job_id, timeout=120):
    deadline = time.monotonic() + timeout
    while (job := client.get(f"/v1/jobs/{job_id}").json())["state"] in ("queued", "running"):
        assert time.monotonic() < deadline, job
        time.sleep(0.1)
    return job


def test_model_simulation_yields_a_dataset_and_separate_truth(client):
    submitted = client.post("/v1/simulations", json=REQUEST)
    assert submitted.status_code == 202, submitted.text
    job = wait(client, submitted.json()["id"])
    assert job["state"] == "succeeded", job
    dataset = client.get(f"/v1/datasets/{job['result']['dataset_id']}").json()
    assert dataset["inputs"] == ["F_x1"] and dataset["outputs"] == ["x1", "x2"]
    assert dataset["periods"] == 3 and dataset["samples"] == 3000 and dataset["fs"] == 500.0
    force = next(c for c in dataset["channels"] if c["name"] == "F_x1")
    np.testing.assert_allclose(force["rms"], 5.0, rtol=1e-9)  # multisine scaled exactly
    truth = client.get(f"/v1/jobs/{job['id']}/artefacts/truth.json").json()
    # undamped natural frequencies of the 2-DOF chain: sqrt(1e4) and sqrt(3e4) rad/s
    exact = np.sqrt([1.0e4, 3.0e4]) / (2 * np.pi)
    np.testing.assert_allclose(truth["modal"]["frequencies"], exact, rtol=1e-9)
    assert "truth" not in str(client.get(f"/v1/datasets/{dataset['id']}").json())


def test_element_without_true_coefficients_is_refused(client):
    request = {**REQUEST, "model": {**REQUEST["model"], "elements": [
        {"kind": "polynomial", "dof": "x1", "exponent": 3}]}}
    response = client.post("/v1/simulations", json=request)
    assert response.status_code == 422
    assert "coefficients" in response.json()["detail"]
