"""fnsi.formats beyond what the service's catalogues show: compressed MATLAB round trips,
limits that hold when a header understates its data, links kept inside HDF5 files."""

from __future__ import annotations

import tracemalloc

import h5py
import numpy as np
import pytest
import scipy.io

from fnsi.formats import (
    DecodedTooLargeError,
    DecodeLimits,
    ReadOptions,
    TooManyChannelsError,
    read_measurement,
)
from tests.service import formats

REC = formats.make_record()


def test_compressed_mat_v5_reads_the_record_exactly(tmp_path):
    path = tmp_path / "r.mat"
    scipy.io.savemat(path, {"u": REC.u, "y": REC.y, "fs": REC.fs, "periods": REC.periods,
                            "output_names": list(REC.output_names)}, do_compression=True)
    measurement, periods = read_measurement(path, "mat")
    np.testing.assert_array_equal(measurement.y[0], REC.y)  # doubles stored exactly
    assert (measurement.output_names, measurement.periods, periods) == (
        REC.output_names, REC.periods, "declared")


def test_mat_names_that_inflate_beyond_the_limit_are_refused(tmp_path):
    """A cell array's dimensions say nothing of its cells: two names of 300,000 characters
    declare 2 cells (8 bytes) and inflate to 1.2 MB (UTF-16), counted while decompressing
    and refused."""
    path = tmp_path / "r.mat"
    names = np.array(["a" * 300_000, "b" * 300_000], dtype=object)
    scipy.io.savemat(path, {"u": REC.u, "y": REC.y, "fs": REC.fs, "output_names": names},
                     do_compression=True)
    with pytest.raises(DecodedTooLargeError, match="output_names decodes to") as refused:
        read_measurement(path, "mat", limits=DecodeLimits(max_decoded_bytes=500_000))
    assert refused.value.limit == 500_000


def test_hdf5_soft_links_are_not_followed(tmp_path):
    """A soft link's path may cross an external link, so none is resolved."""
    path = formats.write_h5(REC, tmp_path / "r.h5")
    with h5py.File(path, "r+") as f:
        f.move("y", "stored_y")
        f["y"] = h5py.SoftLink("/stored_y")
    with pytest.raises(ValueError, match="y is a soft link; links are not followed"):
        read_measurement(path, "h5")


def test_channel_cap_is_checked_on_the_csv_header(tmp_path):
    path = tmp_path / "wide.csv"
    path.write_text(",".join(f"c{k}" for k in range(11)) + "\n" + ",".join("0" * 11) + "\n")
    with pytest.raises(TooManyChannelsError, match="11 channels") as refused:
        read_measurement(path, "csv", ReadOptions(fs=1.0, inputs=("c0",)),
                         DecodeLimits(max_channels=10))
    assert refused.value.limit_name == "max_channels"


def test_npz_members_the_dataset_does_not_use_stay_compressed(tmp_path):
    """An extra member of 160 MB of compressed zeros is never decoded: the read allocates
    about the record (48 kB of samples), nowhere near the member."""
    path = tmp_path / "r.npz"
    np.savez_compressed(path, u=REC.u, y=REC.y, fs=np.float64(REC.fs),
                        junk=np.zeros(20_000_000))
    tracemalloc.start()
    try:
        measurement, _ = read_measurement(path, "npz")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    np.testing.assert_array_equal(measurement.u[0], REC.u)
    assert peak < 10 * 2**20, peak


def test_hdf5_data_in_one_group_are_read_from_it(tmp_path):
    """The one group holding u and y is read; rate and names at the root apply to it."""
    path = formats.write_h5(REC, tmp_path / "r.h5")
    with h5py.File(path, "r+") as f:
        f.create_group("run1")
        for name in ("u", "y"):
            f.move(name, f"run1/{name}")
    m, _ = read_measurement(path, "h5")
    np.testing.assert_array_equal(m.y[0], REC.y)
    assert (m.fs, m.input_names) == (REC.fs, REC.input_names)


def test_a_csv_time_column_with_a_missing_sample_is_refused(tmp_path):
    path = formats.write_csv_with_time(REC, tmp_path / "timed.csv", header="t (ms)")
    lines = path.read_text().splitlines()
    path.write_text("\n".join(lines[:100] + lines[101:]) + "\n")   # row 100 lost
    with pytest.raises(ValueError, match=r"not evenly sampled .* missing or repeated"):
        read_measurement(path, "csv", ReadOptions(inputs=("force",)))


def test_a_csv_time_column_in_milliseconds_gives_the_rate(tmp_path):
    path = tmp_path / "timed.csv"
    t_ms = 1e3 * np.arange(REC.u.shape[0]) / REC.fs
    np.savetxt(path, np.column_stack([t_ms, REC.u, REC.y]), delimiter=",", comments="",
               header="t (ms),force,NC2w_Z,NC2b_Z")
    m, _ = read_measurement(path, "csv", ReadOptions(inputs=("force",)))
    assert m.fs == pytest.approx(REC.fs, rel=1e-12) and m.output_names == REC.output_names


def test_a_group_that_is_not_there_lists_the_root(tmp_path):
    path = formats.write_h5_in_groups(REC, tmp_path / "two.h5", ("run1", "run2"))
    with pytest.raises(ValueError, match=r"no group 'run3'.*\['input_names', 'output_names', "
                                         r"'run1/', 'run2/'\]"):
        read_measurement(path, "h5", ReadOptions(group="run3"))


def test_matlab_v73_iddata_spellings_in_a_group(tmp_path):
    path = formats.write_mat_iddata(REC, tmp_path / "iddata.mat", v73=True)
    with h5py.File(path, "r+") as f:
        f.create_group("run")
        for name in ("InputData", "OutputData", "Ts"):
            f.move(name, f"run/{name}")
    m, _ = read_measurement(path, "mat", ReadOptions(group="/run"))
    np.testing.assert_array_equal(m.y[0], REC.y)
    assert m.fs == pytest.approx(REC.fs, rel=1e-15)  # 1 / (1 / 1000) in doubles


def test_a_variable_given_under_two_spellings_is_refused(tmp_path):
    path = tmp_path / "both.mat"
    scipy.io.savemat(path, {"u": REC.u, "y": REC.y, "fs": REC.fs, "Ts": 1 / REC.fs})
    with pytest.raises(ValueError, match=r"gives fs twice, as \['fs', 'Ts'\]"):
        read_measurement(path, "mat")
