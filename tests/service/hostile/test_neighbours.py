"""Hostile neighbours (issue 19, HTTP layer): a dataset deleted while it is downloaded, and a
tenant uploading a file another tenant holds."""

from __future__ import annotations

import io
import threading
import time
from dataclasses import dataclass

import httpx
import numpy as np
import pytest

from tests.service import formats
from tests.service.hostile.conftest import (
    INTRUDER,
    OWNER,
    PROBLEM,
    Seeded,
    fingerprint,
    npz_bytes,
    settle,
)

# 100,000 samples of three channels: ~2.4 MB as NPZ, ~5 MB as CSV, so that a download and
# the first CSV rendering last long enough for a delete to land in the middle of them.
BIG = formats.make_record(periods=4, period_length=25_000)
DOWNLOADERS = 6


@dataclass(frozen=True)
class Download:
    """What one download got: its format, status, declared length and body."""

    format: str
    status: int
    length: int | None
    body: bytes
    content_type: str


def download_until_gone(url: str, dataset_id: str, first: str, got: list[Download],
                        failures: list[BaseException]) -> None:
    """Download the dataset, alternating CSV and NPZ from ``first``, until it is gone."""
    formats_ = ["csv", "npz"] if first == "csv" else ["npz", "csv"]
    try:
        with httpx.Client(base_url=url, timeout=120, headers={"X-API-Key": OWNER}) as client:
            for k in range(1000):
                fmt = formats_[k % 2]
                reply = client.get(f"/v1/datasets/{dataset_id}/download", params={"format": fmt})
                length = reply.headers.get("content-length")
                got.append(Download(fmt, reply.status_code, None if length is None
                                    else int(length), reply.content,
                                    reply.headers["content-type"]))
                if reply.status_code != 200:
                    return
    except BaseException as err:  # a truncated body or a reset connection: the test fails
        failures.append(err)


def check_download(download: Download, canonical: bytes) -> None:
    """A complete 200 (the whole NPZ, or a CSV of every sample) or a 404 problem."""
    if download.status == 404:
        assert download.content_type == PROBLEM
        assert b"does not exist" in download.body
        return
    assert download.status == 200, download.body[:300]
    assert download.length == len(download.body)
    if download.format == "npz":
        assert download.body == canonical
        return
    header, _, rows = download.body.partition(b"\n")
    assert header == b"force,NC2w_Z,NC2b_Z"
    table = np.loadtxt(io.BytesIO(rows), delimiter=",")
    # %.17g round-trips a float64 exactly
    np.testing.assert_array_equal(table, np.hstack([BIG.u, BIG.y]))


# Deleted as the downloads start, during the first CSV rendering, or while the renderings
# and blobs stream out continuously (both renderings done, six downloads in flight).
@pytest.mark.parametrize("completed", [0, 1, 12], ids=["at-once", "after-one", "streaming"])
def test_delete_during_downloads_gives_whole_bodies_or_404_and_leaves_nothing(seeded: Seeded,
                                                                             completed):
    settle(seeded.stack)
    before = fingerprint(seeded.stack)
    with httpx.Client(base_url=seeded.stack.url, timeout=60,
                      headers={"X-API-Key": OWNER}) as client:
        created = client.post("/v1/datasets", files={"file": ("big.npz", npz_bytes(
            u=BIG.u, y=BIG.y, periods=np.int64(BIG.periods)))})
        assert created.status_code == 201, created.text
        dataset_id = created.json()["id"]
        canonical = client.get(f"/v1/datasets/{dataset_id}/download").content
        got: list[Download] = []
        failures: list[BaseException] = []
        threads = [threading.Thread(target=download_until_gone, args=(
            seeded.stack.url, dataset_id, "csv" if k % 2 else "npz", got, failures))
            for k in range(DOWNLOADERS)]
        for thread in threads:
            thread.start()
        deadline = time.monotonic() + 120
        while sum(d.status == 200 for d in got) < completed:
            assert time.monotonic() < deadline and not failures, (got, failures)
            time.sleep(0.01)
        assert client.delete(f"/v1/datasets/{dataset_id}").status_code == 204
        for thread in threads:
            thread.join(timeout=300)
    assert not failures, failures
    assert sum(d.status == 404 for d in got) == DOWNLOADERS  # every downloader saw the end
    for download in got:
        check_download(download, canonical)
    settle(seeded.stack)
    assert fingerprint(seeded.stack) == before  # no blob, rendering or scratch file left


def blob_names(seeded: Seeded) -> set[str]:
    return {p.name for p in (seeded.stack.data_dir / "blobs").iterdir()}


def test_two_tenants_uploading_one_file_get_separate_blobs(seeded: Seeded):
    """The intruder's upload of the owner's file is parsed and written for the intruder,
    as any new file would be (no shared cache whose speed tells what the owner holds),
    and deleting it leaves the owner's dataset whole."""
    settle(seeded.stack)
    before, blobs = fingerprint(seeded.stack), blob_names(seeded)
    with seeded.connect(INTRUDER) as intruder, seeded.connect(OWNER) as owner:
        stored = owner.get(f"/v1/datasets/{seeded.dataset_id}/download").content
        theirs = intruder.post("/v1/datasets", files={"file": ("rec.npz", npz_bytes())})
        assert theirs.status == 201, theirs.text
        added = blob_names(seeded) - blobs
        assert len(added) == 1 and added.pop().endswith(".npz")
        # the owner's second copy shares the owner's blob: deduplication within a tenant
        again = owner.post("/v1/datasets", files={"file": ("rec.npz", npz_bytes())})
        assert again.status == 201, again.text
        assert len(blob_names(seeded) - blobs) == 1
        deleted = intruder.request("DELETE", f"/v1/datasets/{theirs.json()['id']}")
        assert deleted.status == 204
        assert blob_names(seeded) == blobs
        for dataset_id in (seeded.dataset_id, again.json()["id"]):
            reply = owner.get(f"/v1/datasets/{dataset_id}/download")
            assert reply.status == 200 and reply.content == stored
        assert owner.request("DELETE", f"/v1/datasets/{again.json()['id']}").status == 204
        owner.assert_kept()
    settle(seeded.stack)
    assert fingerprint(seeded.stack) == before

