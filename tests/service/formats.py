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


def write_uff(rec: Record, path: Path, *, binary: bool, output_kinds: tuple[int, ...] = (8, 8),
              units: tuple[str, ...] | None = None, func_type: int = 1,
              abscissa_type: int = 17) -> Path:
    """One dataset-58 (ascii) or 58b (binary) record per channel, all in one file:
    the outputs of ordinate types ``output_kinds`` (8 displacement, 11 velocity, 12
    acceleration), ``units`` the ordinate unit labels of inputs then outputs; function
    type 1 over time (17) unless said otherwise (4 and 18: an FRF over frequency)."""
    channels = [(n, rec.u[:, k], 13) for k, n in enumerate(rec.input_names)]
    channels += [(n, rec.y[:, k], kind) for k, (n, kind) in enumerate(
        zip(rec.output_names, output_kinds, strict=True))]
    labels = units or ("NONE",) * len(channels)
    x = np.arange(rec.u.shape[0]) / rec.fs
    sets = [pyuff.prepare_58(
        binary=int(binary), id1=name, func_type=func_type, rsp_node=k + 1, rsp_dir=3,
        ref_node=1, ref_dir=3, ord_data_type=4, num_pts=x.size, abscissa_spacing=1,
        abscissa_min=0.0, abscissa_inc=1.0 / rec.fs, abscissa_spec_data_type=abscissa_type,
        ordinate_spec_data_type=kind, ordinate_axis_units_lab=label,
        orddenom_spec_data_type=0, z_axis_spec_data_type=0, data=data, x=x)
        for k, ((name, data, kind), label) in enumerate(zip(channels, labels, strict=True))]
    pyuff.UFF(str(path)).write_sets(sets, mode="add")
    return path


# -- layouts of issue 22: what each reader recognises, refuses or hints ---------------------
def write_csv_with_time(rec: Record, path: Path, header: str = "time [s]") -> Path:
    """The CSV with a first column of sample times."""
    t = np.arange(rec.u.shape[0]) / rec.fs
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow([header, *rec.input_names, *rec.output_names])
        writer.writerows(np.column_stack([t, rec.u, rec.y]).tolist())
    return path


def write_mat_iddata(rec: Record, path: Path, *, v73: bool = False) -> Path:
    """The variables MATLAB's iddata properties are saved as: InputData, OutputData, Ts,
    InputName, OutputName, InputUnit, OutputUnit."""
    if v73:
        with h5py.File(path, "w", userblock_size=512) as f:
            for key, value in (("InputData", rec.u), ("OutputData", rec.y),
                               ("Ts", np.array([[1 / rec.fs]]))):
                f.create_dataset(key, data=value.T).attrs["MATLAB_class"] = np.bytes_("double")
        return path
    scipy.io.savemat(path, {"InputData": rec.u, "OutputData": rec.y, "Ts": 1 / rec.fs,
                            "InputName": list(rec.input_names),
                            "OutputName": list(rec.output_names),
                            "InputUnit": ["N"], "OutputUnit": ["mm", "mm"]})
    return path


def write_mat_fs_and_units(rec: Record, path: Path) -> Path:
    """u, y, the Signal Processing spelling Fs and unit cell arrays."""
    scipy.io.savemat(path, {"u": rec.u, "y": rec.y, "Fs": rec.fs, "periods": rec.periods,
                            "input_names": list(rec.input_names),
                            "output_names": list(rec.output_names),
                            "input_units": ["V"], "output_units": ["V", "mV"]})
    return path


def write_mat_wrong_case(rec: Record, path: Path) -> Path:
    """U, Y and FS: the canonical names in capitals."""
    scipy.io.savemat(path, {"U": rec.u, "Y": rec.y, "FS": rec.fs})
    return path


def write_h5_with_unit_attributes(rec: Record, path: Path) -> Path:
    write_h5(rec, path)
    with h5py.File(path, "r+") as f:
        f["u"].attrs["units"] = "N"
        f["y"].attrs["units"] = ["mm", "mm"]
    return path


def write_h5_in_groups(rec: Record, path: Path, groups: tuple[str, ...]) -> Path:
    """The record in each of ``groups`` (outputs scaled by 1, 2, ...); rate at the root."""
    with h5py.File(path, "w") as f:
        f.attrs["fs"] = rec.fs
        f.create_dataset("input_names", data=list(rec.input_names))
        f.create_dataset("output_names", data=list(rec.output_names))
        for k, name in enumerate(groups):
            group = f.create_group(name)
            group.create_dataset("u", data=rec.u)
            group.create_dataset("y", data=(k + 1) * rec.y)
    return path


def write_npz_transposed(rec: Record, path: Path) -> Path:
    """Channels stored in rows, as a MATLAB or LabVIEW export often has them."""
    np.savez(path, u=rec.u.T, y=rec.y.T, fs=np.float64(rec.fs))
    return path


@dataclass(frozen=True)
class Layout:
    """A file of one layout case, the options sent with it and what must come back:
    ``fields`` of the dataset summary (``units``: channel -> unit) when accepted, else
    the HTTP status and words of the refusal."""

    write: object
    options: dict
    fields: dict | None = None
    status: int = 201
    says: tuple[str, ...] = ()


REC_UNITS = {"force": "N", "NC2w_Z": "mm", "NC2b_Z": "mm"}
LAYOUTS = {
    "uff-frf-refused": Layout(
        lambda d: write_uff(make_record(), d / "frf.uff", binary=True, func_type=4,
                            abscissa_type=18), {}, status=422,
        says=("frequency response function", "frequency [hz]", "not a time record")),
    "uff-mixed-quantities-refused": Layout(
        lambda d: write_uff(make_record(), d / "mixed.uff", binary=True, output_kinds=(8, 12)),
        {"periods": 4}, status=422,
        says=("mix quantities", "displacement: ['nc2w_z']", "acceleration: ['nc2b_z']",
              'option outputs, e.g. {"outputs": ["nc2b_z"]}')),
    "uff-one-quantity-chosen": Layout(
        lambda d: write_uff(make_record(), d / "mixed.uff", binary=True, output_kinds=(8, 12)),
        {"periods": 4, "outputs": ["NC2b_Z"]},
        {"quantity": "acceleration", "outputs": ["NC2b_Z"]}),
    "uff-unit-labels": Layout(
        lambda d: write_uff(make_record(), d / "units.uff", binary=False,
                            units=("N", "mm", "mm")), {"periods": 4},
        {"units": REC_UNITS, "fs": 1000.0}),
    "csv-time-column": Layout(
        lambda d: write_csv_with_time(make_record(), d / "timed.csv"),
        {"inputs": ["force"], "periods": 4},
        {"fs": 1000.0, "outputs": ["NC2w_Z", "NC2b_Z"], "samples": 2000}),
    "csv-time-column-disagrees-with-fs": Layout(
        lambda d: write_csv_with_time(make_record(), d / "timed.csv"),
        {"inputs": ["force"], "fs": 500.0}, status=422,
        says=("fs = 500.0 hz was given", "sampled at 1000 hz")),
    "npz-transposed": Layout(
        lambda d: write_npz_transposed(make_record(periods=4, period_length=50), d / "t.npz"),
        {}, status=422, says=("shape (1, 200)", "transposed?", "one sample per row")),
    "npz-transposed-beyond-the-channel-cap": Layout(
        lambda d: write_npz_transposed(make_record(), d / "t.npz"), {}, status=413,
        says=("4000 channels", "transposed?")),
    "mat-iddata-spellings": Layout(
        lambda d: write_mat_iddata(make_record(), d / "iddata.mat"), {"periods": 4},
        {"fs": 1000.0, "inputs": ["force"], "units": REC_UNITS}),
    "mat-v7.3-iddata-spellings": Layout(
        lambda d: write_mat_iddata(make_record(), d / "iddata.mat", v73=True),
        {"periods": 4}, {"fs": 1000.0, "inputs": ["u0"], "outputs": ["y0", "y1"]}),
    "mat-Fs-and-unit-cells": Layout(
        lambda d: write_mat_fs_and_units(make_record(), d / "fs.mat"), {},
        {"fs": 1000.0, "units": {"force": "V", "NC2w_Z": "V", "NC2b_Z": "mV"}}),
    "h5-unit-attributes": Layout(
        lambda d: write_h5_with_unit_attributes(make_record(), d / "units.h5"), {},
        {"units": REC_UNITS}),
    "h5-record-in-one-group": Layout(
        lambda d: write_h5_in_groups(make_record(), d / "one.h5", ("run1",)), {"periods": 4},
        {"fs": 1000.0, "outputs": ["NC2w_Z", "NC2b_Z"]}),
    "h5-records-in-two-groups-refused": Layout(
        lambda d: write_h5_in_groups(make_record(), d / "two.h5", ("run1", "run2")), {},
        status=422, says=("groups ['run1', 'run2'] each hold a record", "option group")),
    "h5-group-chosen": Layout(
        lambda d: write_h5_in_groups(make_record(), d / "two.h5", ("run1", "run2")),
        {"group": "run2", "periods": 4}, {"fs": 1000.0}),
    "mat-names-in-another-case-hinted": Layout(
        lambda d: write_mat_wrong_case(make_record(), d / "case.mat"), {}, status=422,
        says=("lacks variables ['u', 'y']", "names are case-sensitive", "fs to fs")),
    "units-given-with-the-file": Layout(
        lambda d: write_npz(make_record(), d / "rec.npz"), {"units": {"force": "V"}},
        {"units": {"force": "V", "NC2w_Z": None, "NC2b_Z": None}}),
    "units-of-an-unknown-channel-refused": Layout(
        lambda d: write_npz(make_record(), d / "rec.npz"), {"units": {"x9": "mm"}},
        status=422, says=("units name channels ['x9']",)),
}
