"""Cross-cutting API behaviour: problem+json everywhere, API keys, OpenAPI quality."""

from __future__ import annotations

import json

from tests.service import formats

PROBLEM = "application/problem+json"


def test_health_names_the_queue(client):
    body = client.get("/health").json()
    assert body["status"] == "ok" and body["queue"] == "embedded" and body["version"]


def test_unknown_route_is_problem_json(client):
    response = client.get("/v1/nothing-here")
    assert response.status_code == 404
    assert response.headers["content-type"] == PROBLEM
    assert response.json()["instance"] == "/v1/nothing-here"
    assert "/docs" in response.json()["detail"]


def test_wrong_method_is_problem_json(client):
    response = client.put("/health")
    assert response.status_code == 405
    assert response.headers["content-type"] == PROBLEM


def test_validation_error_lists_fields_without_echoing_values(client):
    secret = "s3cr3t-value-that-must-not-come-back"
    response = client.post("/v1/identifications",
                           json={"dataset_id": "ds_x", "band": [50, 5], "block_rows": secret})
    assert response.status_code == 422
    assert response.headers["content-type"] == PROBLEM
    problem = response.json()
    assert secret not in response.text
    # a union type adds the branch that failed to the location
    assert any("block_rows" in e["loc"] for e in problem["errors"])
    assert "block_rows" in problem["detail"]


def test_unknown_dataset_in_a_request_is_422_naming_the_field(client):
    response = client.post("/v1/identifications",
                           json={"dataset_id": "ds_missing", "band": [5, 50], "block_rows": 10})
    assert response.status_code == 422
    assert response.json()["detail"].startswith("dataset_id:")


def test_invalid_nonlinear_element_reports_the_library_message(client):
    element = {"kind": "clearance", "dof": "y0", "gap": 1.0, "exponent": 5}
    response = client.post("/v1/identifications", json={
        "dataset_id": "ds_x", "band": [5, 50], "block_rows": 10, "elements": [element]})
    assert response.status_code == 422
    assert "not parameters of a clearance element" in response.json()["detail"]


def test_oversized_json_body_is_413_problem(make_client):
    client = make_client(max_request_bytes=1000)
    response = client.post("/v1/batches", content=b"{" + b" " * 5000 + b"}",
                           headers={"content-type": "application/json"})
    assert response.status_code == 413
    assert response.headers["content-type"] == PROBLEM
    assert "FNSI_MAX_REQUEST_BYTES" in response.json()["detail"]


def test_api_keys_isolate_callers(make_client, tmp_path):
    client = make_client(api_keys=["alpha", "beta"])
    path = formats.write_npz(formats.make_record(), tmp_path / "rec.npz")
    assert client.post("/v1/datasets", files={"file": (path.name, path.read_bytes())}
                       ).status_code == 401
    created = client.post("/v1/datasets", files={"file": (path.name, path.read_bytes())},
                          headers={"X-API-Key": "alpha"})
    assert created.status_code == 201
    dataset = created.json()["id"]
    assert client.get(f"/v1/datasets/{dataset}", headers={"X-API-Key": "alpha"}
                      ).status_code == 200
    other = client.get(f"/v1/datasets/{dataset}", headers={"X-API-Key": "beta"})
    assert other.status_code == 404 and other.headers["content-type"] == PROBLEM
    assert client.delete(f"/v1/datasets/{dataset}", headers={"X-API-Key": "beta"}
                         ).status_code == 404
    wrong = client.get("/v1/jobs", headers={"X-API-Key": "gamma"})
    assert wrong.status_code == 401 and wrong.headers["content-type"] == PROBLEM
    assert client.get("/health").status_code == 200  # health needs no key


def test_artefact_names_are_never_paths(client):
    store = client.app.state.store
    job = store.create_job("public", "simulation", {"preset": "single"})
    store.request_cancel(job.id)
    store.write_artefact(job.id, "truth.json", b"{}")
    (store.root / "secret.txt").write_text("do not serve")
    for name in ("..%2F..%2Fsecret.txt", "%2E%2E%2Fsecret.txt", "truth.json%00"):
        response = client.get(f"/v1/jobs/{job.id}/artefacts/{name}")
        assert response.status_code == 404, name
        assert "do not serve" not in response.text
    assert client.get(f"/v1/jobs/{job.id}/artefacts/truth.json").json() == {}


def test_openapi_has_stable_operation_ids_and_problem_responses(client):
    schema = client.get("/openapi.json").json()
    ids = {op["operationId"] for path in schema["paths"].values() for op in path.values()}
    assert {"health", "create_dataset", "get_dataset", "download_dataset", "delete_dataset",
            "create_simulation", "create_identification", "create_batch", "get_batch",
            "list_jobs", "get_job", "cancel_job", "list_artefacts", "get_artefact"} <= ids
    upload = schema["paths"]["/v1/datasets"]["post"]
    assert PROBLEM in upload["responses"]["422"]["content"]
    assert "Problem" in schema["components"]["schemas"]
    body = json.dumps(schema["components"]["schemas"]["IdentificationRequest"])
    assert "Analysis band [Hz]" in body
