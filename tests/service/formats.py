"""A known periodic record and writers of it in every upload format, each with that
format's own library (numpy, csv, scipy.io, h5py, pyuff)."""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
import pyuff
import scipy.io


@dataclass(frozen=True)
class Record:
    """u: (samples, 1) force [N]; y: (samples, 2) displacements; truth of the summary."""

    u: np.ndarray
    y: np.ndarray
    fs: float
    periods: int
    noise_std: float
    signal_power: np.ndarray   # (2,) power of the noise-free periodic outputs
    input_names: tuple[str, ...] = ("force",)
    output_names: tuple[str, ...] = ("NC2w_Z", "NC2b_Z")


def make_record(periods: int = 4, period_length: int = 500, fs: float = 1000.0,
                noise_std: float = 0.01, seed: int = 3) -> Record:
    """Random-phase multisine input; outputs two periodic sums of sines plus white noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(periods * period_length) / fs
    f0 = fs / period_length
    lines = np.arange(1, 60)
    phases = rng.uniform(0, 2 * np.pi, lines.size)
    u = np.sin(2 * np.pi * f0 * np.outer(t, lines) + phases).sum(axis=1)[:, None]
    clean = np.column_stack([0.5 * np.sin(2 * np.pi * 3 * f0 * t),
                             0.2 * np.cos(2 * np.pi * 7 * f0 * t)])
    y = clean + noise_std * rng.standard_normal(clean.shape)
    return Record(u=u, y=y, fs=fs, periods=periods, noise_std=noise_std,
                  signal_power=np.mean(clean**2, axis=0))


def write_npz(rec: Record, path: Path, *, with_periods: bool = True) -> Path:
    extra = {"periods": np.int64(rec.periods)} if with_periods else {}
    np.savez(path, u=rec.u, y=rec.y, fs=np.float64(rec.fs),
             input_names=np.array(rec.input_names), output_names=np.array(rec.output_names),
             quantity=np.str_("displacement"), **extra)
    return path


def npz_bytes(rec: Record, **changes) -> bytes:
    """The record's canonical NPZ as bytes, with arrays replaced (None removes one)."""
    arrays = {"u": rec.u, "y": rec.y, "fs": np.float64(rec.fs),
              "input_names": np.array(rec.input_names),
              "output_names": np.array(rec.output_names), "periods": np.int64(rec.periods)}
    arrays.update(changes)
    buffer = io.BytesIO()
    np.savez(buffer, **{k: v for k, v in arrays.items() if v is not None})
    return buffer.getvalue()


def write_csv(rec: Record, path: Path) -> Path:
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow([*rec.input_names, *rec.output_names])
        writer.writerows(np.hstack([rec.u, rec.y]).tolist())
    return path


def write_mat_v5(rec: Record, path: Path) -> Path:
    scipy.io.savemat(path, {"u": rec.u, "y": rec.y, "fs": rec.fs, "periods": rec.periods,
                            "input_names": list(rec.input_names),
                            "output_names": list(rec.output_names)})
    return path


def _matlab_char(f: h5py.File, key: str, text: str) -> None:
    data = f.create_dataset(key, data=np.array([[ord(c)] for c in text], dtype=np.uint16))
    data.attrs["MATLAB_class"] = np.bytes_("char")


def write_mat_v73(rec: Record, path: Path) -> Path:
    """MATLAB v7.3 as MATLAB writes it: HDF5 with a 512-byte header, arrays transposed,
    names as a cell array of char arrays."""
    with h5py.File(path, "w", userblock_size=512) as f:
        for key, value in (("u", rec.u), ("y", rec.y), ("fs", np.array([[rec.fs]]))):
            f.create_dataset(key, data=value.T).attrs["MATLAB_class"] = np.bytes_("double")
        refs = f.create_group("#refs#")
        for key, names in (("input_names", rec.input_names),
                           ("output_names", rec.output_names)):
            cells = []
            for k, name in enumerate(names):
                _matlab_char(refs, f"{key}{k}", name)
                cells.append(refs[f"{key}{k}"].ref)
            cell = f.create_dataset(key, data=np.array([cells], dtype=h5py.ref_dtype))
            cell.attrs["MATLAB_class"] = np.bytes_("cell")
    with open(path, "r+b") as f:
        f.write(b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Sat Nov 21 2026 HDF5 "
                b"schema 1.00 .".ljust(116) + b"\x00" * 8 + b"\x00\x02IM")
    return path


def write_h5(rec: Record, path: Path) -> Path:
    with h5py.File(path, "w") as f:
        f.create_dataset("u", data=rec.u)
        f.create_dataset("y", data=rec.y)
        f.attrs["fs"] = rec.fs
        f.attrs["periods"] = rec.periods
        f.create_dataset("input_names", data=list(rec.input_names))
        f.create_dataset("output_names", data=list(rec.output_names))
    return path


def write_uff(rec: Record, path: Path, *, binary: bool) -> Path:
    """One dataset-58 (ascii) or 58b (binary) record per channel, all in one file."""
    channels = [(n, rec.u[:, k], 13) for k, n in enumerate(rec.input_names)]
    channels += [(n, rec.y[:, k], 8) for k, n in enumerate(rec.output_names)]
    x = np.arange(rec.u.shape[0]) / rec.fs
    sets = [pyuff.prepare_58(
        binary=int(binary), id1=name, func_type=1, rsp_node=k + 1, rsp_dir=3, ref_node=1,
        ref_dir=3, ord_data_type=4, num_pts=x.size, abscissa_spacing=1, abscissa_min=0.0,
        abscissa_inc=1.0 / rec.fs, abscissa_spec_data_type=17, ordinate_spec_data_type=kind,
        orddenom_spec_data_type=0, z_axis_spec_data_type=0, data=data, x=x)
        for k, (name, data, kind) in enumerate(channels)]
    pyuff.UFF(str(path)).write_sets(sets, mode="add")
    return path
