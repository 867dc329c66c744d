"""Hostile uploads (issue 19): files that point outside themselves, decompression bombs,
absurd channel counts, malformed headers and values the identification cannot compute
with. Each is built as its description says and checked by ``check_refused``: the status,
a detail naming the fault, stored data byte-identical, the connection kept.
"""

from __future__ import annotations

import io
import os
import tempfile
import threading
import time
import zipfile
from collections.abc import Callable
from pathlib import Path

import h5py
import numpy as np
import pytest
import pyuff
import scipy.io
from numpy.lib import format as npy

from tests.service import formats
from tests.service.hostile.conftest import (
    REC,
    Connection,
    Reply,
    Seeded,
    api_rss_bytes,
    check_refused,
    npz_bytes,
)

SECRET = b"FNSI-HOSTILE-SECRET-7f3a"  # in files the server must never read for an upload
MIB = 1024**2
# Bombs are refused from headers: well under the 2 s and 100 MiB the issue allows even on
# a loaded machine, while decoding any of them takes seconds and hundreds of MiB.
BOMB_SECONDS, BOMB_GROWTH = 2.0, 100 * MIB


def upload(content: bytes, name: str, meta: str | None = None) -> Callable[[Connection], Reply]:
    data = {} if meta is None else {"meta": meta}
    return lambda c: c.post("/v1/datasets", files={"file": (name, content)}, data=data)


def written(write: Callable[[Path], Path]) -> bytes:
    """Bytes of a file made by ``write`` in a scratch folder."""
    with tempfile.TemporaryDirectory() as folder:
        return write(Path(folder)).read_bytes()


# -- references out of the file -------------------------------------------------------------
@pytest.fixture(scope="module")
def targets(seeded: Seeded, tmp_path_factory) -> dict[str, tuple[str, bytes]]:
    """Files an upload may point at, each with bytes that must never come back: a secret
    raw file, a secret HDF5 file (links and virtual datasets resolve into HDF5), the
    system's password file, and the stack's own record database by a relative path."""
    folder = tmp_path_factory.mktemp("targets")
    raw = folder / "secret.bin"
    raw.write_bytes(SECRET * 1000)
    secret_h5 = folder / "secret.h5"
    with h5py.File(secret_h5, "w") as f:
        f.create_dataset("y", data=np.frombuffer(SECRET * 1000, dtype=np.uint8))
    sqlite = os.path.relpath(seeded.stack.data_dir / "fnsi.sqlite3")
    return {"secret-raw": (str(raw), SECRET), "secret-hdf5": (str(secret_h5), SECRET),
            "etc-passwd": ("/etc/passwd", b"root:"), "own-sqlite": (sqlite, b"SQLite format")}


def pointing_out(kind: str, target: str, matlab: bool) -> bytes:
    """The record as HDF5 (or MATLAB v7.3) with ``y`` replaced by a reference to
    ``target``: external storage, an external link or a virtual dataset."""
    def write(folder: Path) -> Path:
        path = (formats.write_mat_v73(REC, folder / "r.mat") if matlab
                else formats.write_h5(REC, folder / "r.h5"))
        with h5py.File(path, "r+") as f:
            shape = f["y"].shape
            del f["y"]
            if kind == "external-storage":
                f.create_dataset("y", shape=shape, dtype="f8",
                                 external=[(target, 0, h5py.h5f.UNLIMITED)])
            elif kind == "external-link":
                f["y"] = h5py.ExternalLink(target, "/y")
            else:
                layout = h5py.VirtualLayout(shape=shape, dtype="f8")
                layout[...] = h5py.VirtualSource(target, "y", shape=shape)
                f.create_virtual_dataset("y", layout, fillvalue=0.0)
        return path
    return written(write)


REFERENCES = {"external-storage": ("external storage",), "external-link": ("external link",),
              "virtual": ("virtual dataset",)}


@pytest.mark.parametrize("container", ["h5", "mat-v7.3"])
@pytest.mark.parametrize("kind", list(REFERENCES))
@pytest.mark.parametrize("target", ["secret-raw", "secret-hdf5", "etc-passwd", "own-sqlite"])
def test_no_reference_out_of_an_upload_is_followed(seeded, targets, container, kind, target):
    path, marker = targets[target]
    matlab = container == "mat-v7.3"
    content = pointing_out(kind, path, matlab)
    reply = check_refused(seeded, upload(content, "r.mat" if matlab else "r.h5"), 422,
                          ("y", *REFERENCES[kind], "in the file itself"))
    assert marker not in reply.content


# -- decompression bombs ----------------------------------------------------------------------
def npz_zeros(samples: int) -> bytes:
    """A compressed NPZ whose u and y are ``samples`` zeros each (1e8: 1.6 GB in 1.6 MB)."""
    buffer = io.BytesIO()
    zeros = np.zeros((samples, 1))  # untouched pages: no memory until compressed
    np.savez_compressed(buffer, u=zeros, y=zeros, fs=np.float64(REC.fs))
    return buffer.getvalue()


def mat_zeros(samples: int) -> bytes:
    """A compressed MAT v5 whose u and y are ``samples`` zeros each."""
    zeros = np.zeros((samples, 1))
    buffer = io.BytesIO()
    scipy.io.savemat(buffer, {"u": zeros, "y": zeros, "fs": REC.fs}, do_compression=True)
    return buffer.getvalue()


def h5_huge(samples: int, *, external: str | None) -> bytes:
    """u and y of ``samples`` each: gzip-compressed chunks never written (fill values), or
    external storage on ``external`` (/dev/zero: endless zeros)."""
    def write(folder: Path) -> Path:
        with h5py.File(folder / "r.h5", "w") as f:
            for name in ("u", "y"):
                if external is None:
                    f.create_dataset(name, shape=(samples, 1), dtype="f8", chunks=(2**20, 1),
                                     compression="gzip")
                else:
                    f.create_dataset(name, shape=(samples, 1), dtype="f8",
                                     external=[(external, 0, h5py.h5f.UNLIMITED)])
            f.attrs["fs"] = REC.fs
        return folder / "r.h5"
    return written(write)


class Peak:
    """The API's largest resident memory while a request runs, sampled every 5 ms."""

    def __init__(self, seeded: Seeded) -> None:
        self.stack, self.peak, self.done = seeded.stack, 0, threading.Event()
        self.thread = threading.Thread(target=self._sample, daemon=True)

    def _sample(self) -> None:
        while not self.done.is_set():
            self.peak = max(self.peak, api_rss_bytes(self.stack))
            time.sleep(0.005)

    def __enter__(self) -> Peak:
        self.before = api_rss_bytes(self.stack)
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.done.set()
        self.thread.join()


BOMBS = {  # content, file name, status, words of the detail
    "npz-1e8-compressed-zeros": (lambda: npz_zeros(10**8), "bomb.npz", 413,
                                 ("decodes to 1600000", "FNSI_MAX_DECODED_BYTES", "536870912")),
    "mat-v5-600MB-of-zeros": (lambda: mat_zeros(37_500_000), "bomb.mat", 413,
                              ("decodes to 600000", "FNSI_MAX_DECODED_BYTES")),
    "h5-gzip-fill-values": (lambda: h5_huge(10**9, external=None), "bomb.h5", 413,
                            ("decodes to 16000000000", "FNSI_MAX_DECODED_BYTES")),
    "h5-external-dev-zero": (lambda: h5_huge(10**9, external="/dev/zero"), "bomb.h5", 422,
                             ("u has external storage",)),
}


@pytest.mark.parametrize("bomb", list(BOMBS))
def test_a_bomb_is_refused_from_its_headers(seeded, bomb):
    build, name, status, says = BOMBS[bomb]
    content = build()
    measured: dict[str, float] = {}

    def send(connection: Connection) -> Reply:
        with Peak(seeded) as peak:
            start = time.monotonic()
            reply = upload(content, name)(connection)
            measured["seconds"] = time.monotonic() - start
        measured["growth"] = peak.peak - peak.before
        return reply

    check_refused(seeded, send, status, says)
    print(f"{bomb}: {len(content)} bytes refused in {measured['seconds']:.3f} s, API RSS "
          f"+{measured['growth'] / MIB:.1f} MiB (under load)")
    assert measured["seconds"] < BOMB_SECONDS
    assert measured["growth"] < BOMB_GROWTH


# -- channels and headers ---------------------------------------------------------------------
def npz_header_only(shape: tuple[int, ...], body: bytes) -> bytes:
    """An NPZ whose ``u.npy`` header declares ``shape`` of float64 over ``body``."""
    member = io.BytesIO()
    npy.write_array_header_1_0(member, {"descr": "<f8", "fortran_order": False,
                                        "shape": shape})
    buffer = io.BytesIO(npz_bytes(u=None))
    with zipfile.ZipFile(buffer, "a") as archive:
        archive.writestr("u.npy", member.getvalue() + body)
    return buffer.getvalue()


def uff_with_increment(increment: float) -> bytes:
    """The record as UFF 58 with every record's abscissa increment set to ``increment``."""
    def write(folder: Path) -> Path:
        channels = [("force", REC.u[:, 0], 13), ("NC2w_Z", REC.y[:, 0], 8)]
        sets = [pyuff.prepare_58(
            binary=0, id1=n, func_type=1, rsp_node=k + 1, rsp_dir=3, ref_node=1, ref_dir=3,
            ord_data_type=4, num_pts=data.size, abscissa_spacing=1, abscissa_min=0.0,
            abscissa_inc=increment, abscissa_spec_data_type=17, ordinate_spec_data_type=t,
            orddenom_spec_data_type=0, z_axis_spec_data_type=0, data=data,
            x=np.zeros(data.size)) for k, (n, data, t) in enumerate(channels)]
        pyuff.UFF(str(folder / "r.uff")).write_sets(sets, mode="add")
        return folder / "r.uff"
    return written(write)


def mat_with(**variables) -> bytes:
    """The record as MAT v5 with variables replaced."""
    content = {"u": REC.u, "y": REC.y, "fs": REC.fs, "periods": REC.periods, **variables}
    buffer = io.BytesIO()
    scipy.io.savemat(buffer, content)
    return buffer.getvalue()


def wide_csv(columns: int) -> bytes:
    """A CSV of ``columns`` channels and two rows (200,000 columns: 1.2 MB)."""
    header = ",".join(f"c{k}" for k in range(columns))
    row = ",".join("0" for _ in range(columns))
    return f"{header}\n{row}\n{row}\n".encode()


CASES = {  # request, status, words of the detail
    "npz-1e6-output-channels": (
        upload(npz_bytes(u=np.zeros((2, 1)), y=np.zeros((2, 10**6)), input_names=None,
                         output_names=None), "wide.npz"),
        413, ("1000001 channels", "FNSI_MAX_CHANNELS", "1024")),
    "csv-200000-columns": (upload(wide_csv(200_000), "wide.csv", '{"fs": 1000, "inputs": '
                                  '["c0"]}'), 413, ("200000 channels", "FNSI_MAX_CHANNELS")),
    "npz-periods-two-elements": (upload(npz_bytes(periods=np.array([4, 4])), "r.npz"), 422,
                                 ("periods", "shape (2,)")),
    "npz-u-structured-dtype": (
        upload(npz_bytes(u=np.zeros(REC.u.shape[0], dtype=[("a", "f8"), ("b", "f8")])),
               "r.npz"), 422, ("u has a structured dtype", "plain float array")),
    "npz-header-1e12-elements-over-8-bytes": (
        upload(npz_header_only((10**12,), b"\x00" * 8), "r.npz"), 422,
        ("header of u declares", "holds 8 bytes", "corrupt")),
    "mat-v5-fs-empty": (upload(mat_with(fs=np.zeros((0, 0))), "r.mat"), 422,
                        ("fs must be a single value", "shape (0,)")),
    "uff-abscissa-increment-zero": (upload(uff_with_increment(0.0), "r.uff",
                                           '{"periods": 4}'), 422,
                                    ("abscissa increment", "1 / fs")),
    "npz-values-near-1e200": (upload(npz_bytes(y=REC.y * 1e200), "r.npz"), 422,
                              ("y holds values up to", "rescale", "1e+15")),
    "random-bytes-named-npz": (upload(np.random.default_rng(1).bytes(4096), "r.npz"), 422,
                               ("not an npz (zip) file",)),
    "mat-v5-u-cell-array": (
        upload(mat_with(u=np.array([REC.u[:, 0], REC.u[:, 0]], dtype=object)), "r.mat"),
        422, ("u is a matlab cell array", "numeric matrix (samples x channels)")),
    "mat-v5-y-struct": (upload(mat_with(y={"z": REC.y}), "r.mat"), 422,
                        ("y is a matlab struct", "numeric matrix")),
}


@pytest.mark.parametrize("case", list(CASES))
def test_a_malformed_upload_is_a_clear_refusal(seeded, case):
    send, status, says = CASES[case]
    check_refused(seeded, send, status, says)


def test_a_listing_stays_small_at_the_channel_cap(seeded):
    """1024 channels are accepted; a page of datasets carries their count, not their
    names and statistics (GET of the one dataset has those)."""
    content = npz_bytes(u=REC.u, y=np.tile(REC.y, (1, 1023 // 2 + 1))[:, :1023],
                        output_names=None)
    with seeded.connect() as connection:
        created = connection.post("/v1/datasets", files={"file": ("wide.npz", content)})
        assert created.status == 201, created.text
        assert len(created.json()["channels"]) == 1024
        page = connection.get("/v1/datasets", params={"limit": 200})
        item = next(d for d in page.json()["items"] if d["id"] == created.json()["id"])
        assert (item["n_inputs"], item["n_outputs"]) == (1, 1023)
        # an item is its id, name, times and counts: well under 1 kB, whatever the channels
        assert len(page.content) < 1000 * len(page.json()["items"])
        deleted = connection.request("DELETE", f"/v1/datasets/{created.json()['id']}")
        assert deleted.status == 204
