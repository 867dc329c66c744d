"""A catalogue of bad inputs: each is answered with a 4xx problem+json whose detail names
the fault, and leaves every stored dataset, job and artefact exactly as it was."""

from __future__ import annotations

import asyncio
import copy
import hashlib
import json
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import select

from service.schema import batches, blobs, datasets, jobs, uploads
from service.store import JobState
from tests.service import formats
from tests.service.test_simulations import REQUEST as MODEL_SIMULATION

PROBLEM = "application/problem+json"
REC = formats.make_record()  # fs 1000 Hz, 4 periods x 500 samples, force -> NC2w_Z, NC2b_Z
OWNER, STRANGER = "alpha", "beta"
# The record's NPZ is ~50 kB: uploads of it pass, the larger bodies below do not.
UPLOAD_LIMIT = 100_000
CSV_META = {"fs": REC.fs, "inputs": ["force"]}
# A valid identification of the seeded record: 1.5 s kept at 1 kHz, lines in 5-100 Hz.
IDENTIFY = {"band": [5.0, 100.0], "block_rows": 10, "max_order": 10}


@dataclass(frozen=True)
class Seeded:
    """A client (key ``OWNER``) holding one dataset and one queued job with an artefact."""

    client: TestClient
    dataset_id: str
    job_id: str


Send = Callable[[Seeded], httpx.Response]


@dataclass(frozen=True)
class Bad:
    """A bad request, the status it must get and words its detail must contain."""

    send: Send
    status: int
    says: tuple[str, ...]
    settings: dict = field(default_factory=dict)


def npz(**changes) -> bytes:
    """The record's canonical NPZ with arrays replaced (None removes one)."""
    return formats.npz_bytes(REC, **changes)


def corrupted(data: bytes) -> bytes:
    """The NPZ with bytes inside the first member overwritten: the zip CRC no longer fits."""
    broken = bytearray(data)
    broken[200:400] = b"\xff" * 200
    return bytes(broken)


def half_of(write: Callable[[Path], Path]) -> bytes:
    """First half of a file written by one of the ``formats`` writers (a cut transfer)."""
    with tempfile.TemporaryDirectory() as folder:
        data = write(Path(folder)).read_bytes()
    return data[: len(data) // 2]


def upload(content: bytes, name: str = "rec.npz", meta: dict | str | None = None) -> Send:
    data = {} if meta is None else {"meta": meta if isinstance(meta, str) else json.dumps(meta)}
    return lambda s: s.client.post("/v1/datasets", files={"file": (name, content)}, data=data)


def csv_upload(text: str, meta: dict | None = None) -> Send:
    return upload(text.encode(), "rec.csv", CSV_META if meta is None else meta)


def identify(**changes) -> Send:
    return lambda s: s.client.post("/v1/identifications",
                                   json={"dataset_id": s.dataset_id, **IDENTIFY, **changes})


def element(**spec) -> Send:
    return identify(elements=[{"kind": "polynomial", "dof": "NC2w_Z", "exponent": 3, **spec}])


def simulate(change: Callable[[dict], object]) -> Send:
    """POST the generic test simulation after ``change`` edited a copy of it in place."""
    def send(s: Seeded) -> httpx.Response:
        request = copy.deepcopy(MODEL_SIMULATION)
        change(request)
        return s.client.post("/v1/simulations", json=request)
    return send


def stranger(method: str, path: str) -> Send:
    """A request by another API key on the seeded objects ({d}: dataset, {j}: job)."""
    return lambda s: s.client.request(method, path.format(d=s.dataset_id, j=s.job_id),
                                      headers={"X-API-Key": STRANGER})


def raw(path: str, body: bytes, content_type: str | None) -> Send:
    headers = {} if content_type is None else {"content-type": content_type}
    return lambda s: s.client.post(path, content=body, headers=headers)


BAD: dict[str, Bad] = {
    # -- files that are not a measurement
    "npz-truncated": Bad(upload(npz()[: len(npz()) // 2]), 422, ("npz", "readable")),
    "npz-corrupt-crc": Bad(upload(corrupted(npz())), 422, ("npz", "readable")),
    "npz-object-array": Bad(upload(npz(u=np.array([1.0, "a"], dtype=object))), 422,
                            ("object arrays",)),
    "npz-without-y": Bad(upload(npz(y=None)), 422, ("lacks required arrays", "y")),
    "empty-file": Bad(upload(b""), 422, ("empty",)),
    "mat-truncated": Bad(upload(half_of(lambda d: formats.write_mat_v5(REC, d / "r.mat")),
                                "rec.mat"), 422, ("matlab", "readable")),
    "h5-truncated": Bad(upload(half_of(lambda d: formats.write_h5(REC, d / "r.h5")), "rec.h5"),
                        422, ("hdf5", "readable")),
    # the cut falls after the input record: the outputs are missing
    "uff-truncated": Bad(upload(half_of(lambda d: formats.write_uff(REC, d / "r.uff",
                                                                    binary=True)),
                                "rec.uff", {"periods": REC.periods}), 422, ("uff", "output")),
    "csv-ragged-rows": Bad(csv_upload("force,NC2w_Z\n1,2\n3\n4,5\n"), 422,
                           ("csv", "number of columns")),
    "csv-text-in-numbers": Bad(csv_upload("force,NC2w_Z\n1,2\n3,abc\n"), 422,
                               ("numeric", "abc")),
    "csv-unknown-input-column": Bad(csv_upload("force,NC2w_Z\n1,2\n", {"fs": 10,
                                                                      "inputs": ["F"]}),
                                    422, ("no column", "F")),
    "csv-not-utf8": Bad(upload("force,y\n1,2\n".encode("utf-16"), "rec.csv", CSV_META), 422,
                        ("utf-8",)),
    # -- measurements that are not valid
    "nan-in-y": Bad(upload(npz(y=np.where(np.arange(REC.y.size).reshape(REC.y.shape) == 7,
                                          np.nan, REC.y))), 422, ("nan or infinite", "y")),
    "inf-in-csv": Bad(csv_upload("force,NC2w_Z\n1,2\n3,inf\n"), 422, ("nan or infinite",)),
    "zero-length": Bad(upload(npz(u=np.zeros((0, 1)), y=np.zeros((0, 2)))), 422, ("empty",)),
    "u-y-lengths-differ": Bad(upload(npz(y=REC.y[:-10])), 422,
                              ("same realisations and samples",)),
    "periods-do-not-divide": Bad(upload(npz(periods=np.int64(3))), 422,
                                 ("periods=3 does not divide", "2000")),
    "meta-periods-do-not-divide": Bad(upload(npz(), meta={"periods": 7}), 422,
                                      ("does not divide",)),
    "fs-zero-in-file": Bad(upload(npz(fs=np.float64(0.0))), 422,
                           ("fs must be a positive sampling rate",)),
    "fs-negative-in-meta": Bad(upload(npz(), meta={"fs": -5}), 422, ("fs", "greater than 0")),
    "meta-not-json": Bad(upload(npz(), meta="{fs: 1"), 422, ("meta", "json")),
    "meta-unknown-field": Bad(upload(npz(), meta={"sampling": 1}), 422, ("sampling",)),
    # -- identifications the dataset cannot support, refused at submission
    "band-beyond-nyquist": Bad(identify(band=[5.0, 600.0]), 422, ("nyquist", "500")),
    "band-decreasing": Bad(identify(band=[50.0, 5.0]), 422, ("band", "low < high")),
    "unknown-output": Bad(identify(outputs=["NC2w_Z", "tip"]), 422, ("outputs", "'tip'")),
    "unknown-input": Bad(identify(inputs=["shaker"]), 422, ("inputs", "'shaker'")),
    "unknown-element-dof": Bad(element(dof="W_Z"), 422, ("elements[0].dof", "'W_Z'")),
    "unknown-element-ref": Bad(element(ref="base"), 422, ("elements[0].ref", "'base'")),
    "element-outside-chosen-outputs": Bad(
        identify(outputs=["NC2b_Z"], elements=[{"kind": "polynomial", "dof": "NC2w_Z",
                                                "exponent": 3}]),
        422, ("elements[0].dof", "'NC2w_Z'")),
    "order-beyond-block-rows": Bad(identify(block_rows=3, order=10, max_order=20), 422,
                                   ("order 10", "block_rows")),
    "block-rows-beyond-data": Bad(identify(block_rows=2000, max_order=10), 422,
                                  ("too many block rows",)),
    "spline-knots-not-increasing": Bad(identify(elements=[
        {"kind": "spline", "dof": "NC2w_Z", "knots": [-1.0, 1.0, 0.5]}]), 422,
        ("knots", "strictly increasing")),
    "discard-every-period": Bad(identify(discard_periods=4), 422, ("discard_periods=4",)),
    # ~28 MiB of working memory (block_rows 400 on 1500 real columns) against a 1 MiB limit
    "memory-beyond-limit": Bad(identify(band=[0.5, 499.0], block_rows=400, max_order=10), 422,
                               ("mib", "limit", "block_rows"), {"memory_limit_mb": 1.0}),
    "simulation-too-large": Bad(lambda s: s.client.post("/v1/simulations", json={
        "preset": "single", "periods": 1000, "samples_per_period": 10_000_000}), 422,
        ("samples requested", "at most")),
    "batch-too-long": Bad(lambda s: s.client.post("/v1/batches", json={"jobs": [
        {"kind": "simulation", "request": {"preset": "single"}}] * 1001}), 422,
        ("jobs", "at most 1000")),
    # -- simulations the model cannot support, refused at submission
    "simulation-unknown-force-dof": Bad(simulate(
        lambda r: r["excitation"]["inputs"][0].update(direction={"x9": 1.0})), 422,
        ("excitation.inputs[0].direction", "'x9'")),
    "simulation-unknown-output": Bad(simulate(lambda r: r.update(outputs=["x1", "x9"])), 422,
                                     ("outputs", "'x9'")),
    "simulation-no-outputs": Bad(simulate(lambda r: r.update(outputs=[])), 422,
                                 ("outputs", "at least 1")),
    "simulation-noise-reference-not-measured": Bad(simulate(
        lambda r: r.update(outputs=["x2"], noise_reference="x1")), 422,
        ("noise_reference", "'x1'")),
    "simulation-fs-int-not-a-multiple": Bad(simulate(lambda r: r.update(fs_int=1234.5)), 422,
                                            ("fs_int", "integer multiple")),
    "simulation-band-beyond-nyquist": Bad(simulate(
        lambda r: r["excitation"].update(band=[5.0, 400.0])), 422, ("band", "250")),
    "simulation-matrices-of-two-sizes": Bad(simulate(lambda r: r["model"].update(M=[[1.0]])),
                                            422, ("square matrices",)),
    "simulation-element-on-unknown-dof": Bad(simulate(
        lambda r: r["model"]["elements"][0].update(dof="x9")), 422, ("'x9'",)),
    # -- sizes
    "upload-declared-beyond-limit": Bad(upload(b"0" * (UPLOAD_LIMIT + 2 * 2**20)), 413,
                                        ("FNSI_MAX_UPLOAD_BYTES",)),
    "upload-file-beyond-limit": Bad(upload(npz(u=np.tile(REC.u, (3, 1)),
                                               y=np.tile(REC.y, (3, 1)))), 413,
                                    ("upload limit", str(UPLOAD_LIMIT))),
    "meta-beyond-limit": Bad(upload(npz(), meta={"name": "x" * 70_000}), 400,
                             ("meta", "FNSI_MAX_META_BYTES")),
    # -- names and ids that are not the caller's
    "artefact-dotdot": Bad(lambda s: s.client.get(f"/v1/jobs/{s.job_id}/artefacts/%2E%2E"),
                           404, ("no artefact",)),
    "artefact-slash": Bad(lambda s: s.client.get(
        f"/v1/jobs/{s.job_id}/artefacts/..%2Fresult.json"), 404, ("no route",)),
    "artefact-backslash": Bad(lambda s: s.client.get(
        f"/v1/jobs/{s.job_id}/artefacts/..%5Cfnsi.sqlite3"), 404, ("no artefact",)),
    "other-key-gets-dataset": Bad(stranger("GET", "/v1/datasets/{d}"), 404, ("does not exist",)),
    "other-key-downloads-dataset": Bad(stranger("GET", "/v1/datasets/{d}/download"), 404,
                                       ("does not exist",)),
    "other-key-deletes-dataset": Bad(stranger("DELETE", "/v1/datasets/{d}"), 404,
                                     ("does not exist",)),
    "other-key-gets-job": Bad(stranger("GET", "/v1/jobs/{j}"), 404, ("does not exist",)),
    "other-key-cancels-job": Bad(stranger("DELETE", "/v1/jobs/{j}"), 404, ("does not exist",)),
    "other-key-lists-artefacts": Bad(stranger("GET", "/v1/jobs/{j}/artefacts"), 404,
                                     ("does not exist",)),
    "other-key-identifies-dataset": Bad(lambda s: s.client.post(
        "/v1/identifications", json={"dataset_id": s.dataset_id, **IDENTIFY},
        headers={"X-API-Key": STRANGER}), 422, ("dataset_id", "does not exist")),
    "unknown-api-key": Bad(lambda s: s.client.get("/v1/jobs", headers={"X-API-Key": "gamma"}),
                           401, ("api key",)),
    # -- bodies that are not what the route reads
    "malformed-json": Bad(raw("/v1/identifications", b'{"dataset_id": ', "application/json"),
                          422, ("json",)),
    "json-as-text-plain": Bad(raw("/v1/identifications", json.dumps(IDENTIFY).encode(),
                                  "text/plain"), 422, ("application/json",)),
    "form-to-json-route": Bad(lambda s: s.client.post("/v1/simulations",
                                                      data={"preset": "single"}),
                              422, ("application/json",)),
    "json-to-upload-route": Bad(lambda s: s.client.post("/v1/datasets", json={"file": "x"}),
                                422, ("file",)),
    "bool-as-integer": Bad(lambda s: s.client.post("/v1/simulations", json={
        "preset": "single", "seed": True}), 422, ("seed", "integer")),
    "string-as-integer": Bad(identify(block_rows="10"), 422, ("block_rows", "integer")),
    "bad-cursor": Bad(lambda s: s.client.get("/v1/jobs?cursor=Zm9vOmJhcg"), 422,
                      ("cursor",)),
}


def seed(client: TestClient) -> Seeded:
    """Upload the record and store a queued job with an artefact (nothing runs it)."""
    client.app.state.queue.stop()
    client.headers["X-API-Key"] = OWNER
    created = client.post("/v1/datasets", files={"file": ("rec.npz", npz())})
    assert created.status_code == 201, created.text
    store = client.app.state.store
    owner = store.get_dataset(created.json()["id"]).owner
    job = store.create_job(owner, "simulation", {"preset": "single"})
    store.write_artefact(job.id, "result.json", b"{}")
    return Seeded(client, created.json()["id"], job.id)


def snapshot(seeded: Seeded) -> dict:
    """Everything a bad request must leave alone: records, blobs, artefacts, tmp files."""
    store = seeded.client.app.state.store
    with store.db.read() as db:
        tables = {t.name: db.execute(select(t).order_by(*t.c)).all()
                  for t in (datasets, blobs, jobs, batches, uploads)}
    files = sorted((str(p.relative_to(store.root)), hashlib.sha256(p.read_bytes()).hexdigest())
                   for p in store.root.rglob("*")
                   if p.is_file() and not p.name.startswith("fnsi.sqlite3"))
    return {"tables": tables, "files": files}


@pytest.mark.parametrize("name", list(BAD))
def test_bad_input_is_a_4xx_problem_naming_the_fault(make_client, name):
    bad = BAD[name]
    seeded = seed(make_client(api_keys=[OWNER, STRANGER], max_upload_bytes=UPLOAD_LIMIT,
                              **bad.settings))
    before = snapshot(seeded)
    response = bad.send(seeded)
    assert response.status_code == bad.status, response.text
    assert response.headers["content-type"] == PROBLEM
    problem = response.json()
    assert problem["status"] == bad.status
    for words in bad.says:
        assert words.lower() in problem["detail"].lower(), problem["detail"]
    assert snapshot(seeded) == before
    job = seeded.client.app.state.store.get_job(seeded.job_id)
    assert job.state == JobState.QUEUED and not job.cancel_requested


async def _stream_upload(app, chunks: int, chunk: bytes) -> tuple[int, int, dict]:
    """POST a chunked multipart upload straight to the ASGI app; returns the status, how
    many chunks the app read and the problem it answered."""
    boundary = b"fnsiboundary"
    head = (b"--" + boundary + b'\r\nContent-Disposition: form-data; name="file"; '
            b'filename="big.npz"\r\nContent-Type: application/octet-stream\r\n\r\n')
    read = 0

    async def receive() -> dict:
        nonlocal read
        read += 1
        body = head if read == 1 else chunk
        return {"type": "http.request", "body": body, "more_body": read <= chunks}

    sent: list[dict] = []

    async def send(message: dict) -> None:
        sent.append(message)

    scope = {"type": "http", "asgi": {"version": "3.0"}, "http_version": "1.1",
             "method": "POST", "scheme": "http", "path": "/v1/datasets", "raw_path":
             b"/v1/datasets", "query_string": b"", "root_path": "", "server": ("test", 80),
             "client": ("test", 1), "headers": [
                 (b"content-type", b"multipart/form-data; boundary=" + boundary),
                 (b"transfer-encoding", b"chunked"), (b"x-api-key", OWNER.encode())]}
    await app(scope, receive, send)
    start = next(m for m in sent if m["type"] == "http.response.start")
    body = b"".join(m.get("body", b"") for m in sent if m["type"] == "http.response.body")
    return start["status"], read, json.loads(body)


def test_streamed_upload_is_refused_at_the_limit(make_client):
    """A chunked upload (no Content-Length) is cut off once the limit is passed, not read
    to its end, and leaves no partial file behind."""
    seeded = seed(make_client(api_keys=[OWNER, STRANGER], max_upload_bytes=UPLOAD_LIMIT))
    before = snapshot(seeded)
    chunk, chunks = b"\x00" * 65536, 200  # 12.5 MiB offered
    status, read, problem = asyncio.run(_stream_upload(seeded.client.app, chunks, chunk))
    assert status == 413 and "FNSI_MAX_UPLOAD_BYTES" in problem["detail"]
    # the middleware allows the file limit plus 1 MiB of multipart framing
    allowed = UPLOAD_LIMIT + 2**20
    assert read <= allowed // len(chunk) + 3, f"read {read} of {chunks} chunks"
    assert snapshot(seeded) == before
    assert list(seeded.client.app.state.store.tmp.iterdir()) == []


@pytest.mark.parametrize("changes", [
    {},
    # order "auto": the library caps max_order at l (i - 1) = 18 instead of refusing it
    {"block_rows": 10, "max_order": 60},
    {"elements": [{"kind": "spline", "dof": "NC2w_Z", "ref": "NC2b_Z", "intervals": 4}]},
], ids=["baseline", "max-order-above-the-cap", "spline"])
def test_the_checks_accept_what_the_library_accepts(make_client, changes):
    """Controls of the catalogue: a valid identification of the seeded record is queued."""
    seeded = seed(make_client(api_keys=[OWNER, STRANGER]))
    response = identify(**changes)(seeded)
    assert response.status_code == 202, response.text
    assert response.json()["state"] == "queued"
