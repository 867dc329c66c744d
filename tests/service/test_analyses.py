"""POST /v1/analyses: the distortion analysis as a job, its result, figure and refusals."""

from __future__ import annotations

import io

import numpy as np

from fnsi.excitation import multisine
from tests.service.test_simulations import wait

FS, N, PERIODS = 256.0, 512, 4


def cubic_record() -> bytes:
    """A cubic and a linear output of a random-odd multisine, 0.1 % noise (NPZ bytes)."""
    u = np.tile(multisine(N, FS, (2.0, 40.0), 1.0, lines="odd", detection=4)[0], PERIODS)
    noise = 1e-3 * np.random.default_rng(0).standard_normal((u.size, 2))
    y = np.column_stack([u + 0.1 * u**3, u]) + noise
    buffer = io.BytesIO()
    np.savez(buffer, u=u, y=y, fs=FS, periods=PERIODS,
             output_names=np.array(["cubic", "linear"]))
    return buffer.getvalue()


def upload(client) -> str:
    created = client.post("/v1/datasets", files={"file": ("cubic.npz", cubic_record())})
    assert created.status_code == 201, created.text
    return created.json()["id"]


def test_an_analysis_job_finds_the_odd_distortions_of_the_cubic_output_only(client):
    submitted = client.post("/v1/analyses", json={"dataset_id": upload(client)})
    assert submitted.status_code == 202, submitted.text
    job = wait(client, submitted.json()["id"])
    assert job["state"] == "succeeded", job
    result = job["result"]
    channels = {c["name"]: c for c in result["channels"]}
    assert channels["cubic"]["odd"]["above_noise"] and channels["cubic"]["odd"]["level_db"] > 20
    assert not channels["linear"]["odd"]["above_noise"]
    assert not channels["cubic"]["even"]["above_noise"]
    assert result["odd_design"] and "odd nonlinear distortions" in result["verdict"]
    names = {a["name"] for a in client.get(f"/v1/jobs/{job['id']}/artefacts").json()}
    assert {"analysis.json", "distortion.png", "report.html"} <= names
    png = client.get(f"/v1/jobs/{job['id']}/artefacts/distortion.png")
    assert png.content.startswith(b"\x89PNG") and len(png.content) > 20_000


def test_an_analysis_that_cannot_run_is_refused_at_submission(client):
    dataset_id = upload(client)
    for body, words in (({"outputs": ["tip"]}, "'tip'"),
                        ({"outputs": ["cubic", "cubic"]}, "more than once"),
                        ({"discard_periods": 3}, "at least two periods")):
        refused = client.post("/v1/analyses", json={"dataset_id": dataset_id, **body})
        assert refused.status_code == 422 and words in refused.json()["detail"], refused.text
    assert client.get("/v1/jobs").json()["items"] == []
