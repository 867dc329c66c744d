"""Dataset routes: every upload format, summary truth, download, dedup, delete, limits."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest

from tests.service import formats

REC = formats.make_record()

UPLOADS = {
    "npz": (lambda p: formats.write_npz(REC, p / "rec.npz"), None),
    "csv": (lambda p: formats.write_csv(REC, p / "rec.csv"),
            {"fs": REC.fs, "inputs": ["force"], "periods": REC.periods}),
    "mat-v5": (lambda p: formats.write_mat_v5(REC, p / "rec.mat"), None),
    "mat-v7.3": (lambda p: formats.write_mat_v73(REC, p / "rec.mat"), {"periods": REC.periods}),
    "h5": (lambda p: formats.write_h5(REC, p / "rec.h5"), None),
    "uff58": (lambda p: formats.write_uff(REC, p / "rec.uff", binary=False),
              {"periods": REC.periods}),
    "uff58b": (lambda p: formats.write_uff(REC, p / "rec.uff", binary=True),
               {"periods": REC.periods}),
}


def upload(client, path, meta=None, headers=None):
    files = {"file": (path.name, path.read_bytes())}
    data = {"meta": json.dumps(meta)} if meta is not None else {}
    return client.post("/v1/datasets", files=files, data=data, headers=headers or {})


@pytest.mark.parametrize("fmt", list(UPLOADS))
def test_every_format_uploads_to_the_same_measurement(client, tmp_path, fmt):
    write, meta = UPLOADS[fmt]
    response = upload(client, write(tmp_path), meta)
    assert response.status_code == 201, response.text
    body = response.json()
    assert body["fs"] == REC.fs
    assert body["samples"] == REC.u.shape[0]
    assert body["periods"] == REC.periods
    assert body["inputs"] == ["force"] and body["outputs"] == ["NC2w_Z", "NC2b_Z"]
    downloaded = client.get(f"/v1/datasets/{body['id']}/download?format=npz")
    assert downloaded.status_code == 200
    with np.load(io.BytesIO(downloaded.content), allow_pickle=False) as data:
        # ASCII UFF 58 stores 13 significant digits at most (E20.12 fields); binary is exact.
        np.testing.assert_allclose(data["y"], REC.y, rtol=1e-11, atol=1e-14)
        np.testing.assert_allclose(data["u"], REC.u, rtol=1e-11, atol=1e-14)


def test_summary_rms_and_snr_match_the_known_signal(client, tmp_path):
    body = upload(client, formats.write_npz(REC, tmp_path / "rec.npz")).json()
    channels = {c["name"]: c for c in body["channels"]}
    np.testing.assert_allclose(channels["force"]["rms"], np.sqrt(np.mean(REC.u**2)), rtol=1e-12)
    # the input is noise-free: only rounding differs between periods (~1e-13 relative)
    assert channels["force"]["snr_db"] > 200
    truth_db = 10 * np.log10(REC.signal_power / REC.noise_std**2)
    measured = [channels[n]["snr_db"] for n in REC.output_names]
    # 1500 noise samples (3 periods after the transient one x 500): the noise variance is
    # known to sqrt(2/1000) ~ 4.5 %, i.e. 0.2 dB; 0.5 dB leaves room.
    np.testing.assert_allclose(measured, truth_db, atol=0.5)


def test_periods_are_detected_when_not_declared(client, tmp_path):
    body = upload(client, formats.write_npz(REC, tmp_path / "rec.npz", with_periods=False))
    assert body.json()["periods"] == REC.periods
    assert body.json()["periods_source"] == "detected"


def test_identical_upload_shares_storage_but_gets_its_own_id(client, tmp_path):
    path = formats.write_npz(REC, tmp_path / "rec.npz")
    first, second = upload(client, path).json(), upload(client, path).json()
    assert first["id"] != second["id"]
    assert len(list(client.app.state.store.blobs.glob("*.npz"))) == 1
    assert client.delete(f"/v1/datasets/{first['id']}").status_code == 204
    assert client.get(f"/v1/datasets/{first['id']}").status_code == 404
    # the blob survives while the second dataset uses it
    assert client.get(f"/v1/datasets/{second['id']}/download").status_code == 200
    assert client.delete(f"/v1/datasets/{second['id']}").status_code == 204
    assert list(client.app.state.store.blobs.glob("*.npz")) == []


def test_csv_download_round_trips(client, tmp_path):
    body = upload(client, formats.write_npz(REC, tmp_path / "rec.npz")).json()
    response = client.get(f"/v1/datasets/{body['id']}/download?format=csv")
    assert response.status_code == 200
    assert response.headers["content-type"].startswith("text/csv")
    header, *rows = response.text.splitlines()
    assert header == "force,NC2w_Z,NC2b_Z"
    np.testing.assert_allclose(np.loadtxt(rows, delimiter=","), np.hstack([REC.u, REC.y]),
                               rtol=1e-15)


def test_csv_without_fs_is_refused_with_a_hint(client, tmp_path):
    response = upload(client, formats.write_csv(REC, tmp_path / "rec.csv"))
    assert response.status_code == 422
    assert response.headers["content-type"] == "application/problem+json"
    assert "fs" in response.json()["detail"] and "inputs" in response.json()["detail"]


@pytest.mark.parametrize("content", [b"not a zip file at all", b"\x00" * 100])
def test_garbage_npz_is_a_clear_422_without_echo(client, content):
    response = client.post("/v1/datasets", files={"file": ("x.npz", content)})
    assert response.status_code == 422
    problem = response.json()
    assert problem["status"] == 422 and "npz" in problem["detail"]
    assert "not a zip" not in response.text.replace("not a zip file", "")


def test_pickled_npz_is_refused(client, tmp_path):
    path = tmp_path / "evil.npz"
    np.savez(path, u=np.ones(8), y=np.ones(8), fs=1.0, input_names=np.array([{"a": 1}]))
    response = upload(client, path)
    assert response.status_code == 422
    assert "object arrays" in response.json()["detail"]


def test_unknown_extension_asks_for_a_format(client):
    response = client.post("/v1/datasets", files={"file": ("rec.bin", b"123")})
    assert response.status_code == 422
    assert "meta.format" in response.json()["detail"]


def test_bad_meta_is_a_422_naming_the_field(client, tmp_path):
    response = upload(client, formats.write_npz(REC, tmp_path / "rec.npz"), {"fs": -1})
    assert response.status_code == 422
    assert "fs" in response.json()["detail"]


def test_upload_over_the_limit_is_413(make_client, tmp_path):
    client = make_client(max_upload_bytes=10_000)
    path = formats.write_npz(REC, tmp_path / "rec.npz")  # ~ 50 kB
    response = upload(client, path)
    assert response.status_code == 413
    assert response.headers["content-type"] == "application/problem+json"
    assert "FNSI_MAX_UPLOAD_BYTES" in response.json()["detail"]
    assert list(client.app.state.store.tmp.iterdir()) == []


def test_dataset_pages_follow_cursors_newest_first_per_key(make_client, tmp_path):
    client = make_client(api_keys="alice,bob")
    path = formats.write_npz(REC, tmp_path / "rec.npz")
    alice, bob = {"X-API-Key": "alice"}, {"X-API-Key": "bob"}
    ids = [upload(client, path, {"name": f"run{k}"}, alice).json()["id"] for k in range(5)]
    upload(client, path, None, bob)
    assert client.delete(f"/v1/datasets/{ids[2]}", headers=alice).status_code == 204
    seen, cursor = [], None
    while True:
        page = client.get("/v1/datasets", headers=alice,
                          params={"limit": 2, **({"cursor": cursor} if cursor else {})}).json()
        seen += page["items"]
        cursor = page["next_cursor"]
        if cursor is None:
            break
    assert [d["id"] for d in seen] == [ids[4], ids[3], ids[1], ids[0]]
    assert [d["name"] for d in seen] == ["run4", "run3", "run1", "run0"]
    assert (seen[0]["n_inputs"], seen[0]["n_outputs"], seen[0]["fs"]) == (1, 2, REC.fs)
    # a listing carries counts; the channels come with GET of one dataset
    assert "channels" not in seen[0] and "outputs" not in seen[0]
    one = client.get(f"/v1/datasets/{ids[4]}", headers=alice).json()
    assert one["outputs"] == ["NC2w_Z", "NC2b_Z"] and one["n_outputs"] == 2
    assert len(client.get("/v1/datasets", headers=bob).json()["items"]) == 1
    for bad in ("garbage", "am9iOjE"):  # the second is a job cursor ("job:1")
        response = client.get("/v1/datasets", headers=alice, params={"cursor": bad})
        assert response.status_code == 422
        assert response.headers["content-type"] == "application/problem+json"
