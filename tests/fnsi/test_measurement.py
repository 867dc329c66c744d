"""Measurement container: validation and canonical NPZ / CSV files."""

from __future__ import annotations

import io

import numpy as np
import pytest

from fnsi.measurement import Measurement


@pytest.fixture
def record():
    rng = np.random.default_rng(0)
    return Measurement.from_arrays(rng.standard_normal((2, 12, 1)),
                                   rng.standard_normal((2, 12, 2)), 50.0, periods=3,
                                   input_names=["F"], output_names=["F", "x2"],
                                   quantity="acceleration")


def test_shapes_names_and_properties():
    m = Measurement.from_arrays(np.arange(8.0), np.zeros((8, 3)), 10.0, periods=4)
    assert m.u.shape == (1, 8, 1) and m.y.shape == (1, 8, 3)
    assert m.input_names == ("u0",) and m.output_names == ("y0", "y1", "y2")
    assert (m.n_inputs, m.n_outputs, m.n_samples, m.n_realisations, m.period_length) == \
        (1, 3, 8, 1, 2)
    assert m.output_index("y2") == 2
    sub = m.select(outputs=["y2", "y0"])
    assert sub.output_names == ("y2", "y0") and sub.y.shape == (1, 8, 2)


def test_npz_round_trip_with_realisations(record, tmp_path):
    path = tmp_path / "m.npz"
    record.to_npz(path)
    back = Measurement.from_npz(path)
    np.testing.assert_array_equal(back.u, record.u)
    np.testing.assert_array_equal(back.y, record.y)
    assert (back.fs, back.periods, back.quantity) == (50.0, 3, "acceleration")
    assert back.output_names == ("F", "x2")


def test_npz_single_realisation_is_two_dimensional(tmp_path):
    m = Measurement.from_arrays(np.ones(4), np.ones((4, 2)), 10.0)
    m.to_npz(tmp_path / "s.npz")
    with np.load(tmp_path / "s.npz") as f:
        assert f["u"].shape == (4,) or f["u"].shape == (4, 1)
        assert f["y"].shape == (4, 2)


def test_npz_with_objects_or_missing_arrays_is_refused(tmp_path):
    np.savez(tmp_path / "o.npz", u=np.ones(4), y=np.ones(4), fs=10.0,
             output_names=np.array(["a"], dtype=object))
    with pytest.raises(ValueError, match="object arrays"):
        Measurement.from_npz(tmp_path / "o.npz")
    np.savez(tmp_path / "m.npz", u=np.ones(4), fs=10.0)
    with pytest.raises(ValueError, match=r"\['y'\]"):
        Measurement.from_npz(tmp_path / "m.npz")


def test_csv_round_trip_with_a_driving_point(tmp_path):
    m = Measurement.from_arrays(np.arange(6.0), np.arange(12.0).reshape(6, 2), 20.0,
                                input_names=["F"], output_names=["F", "x"], periods=2)
    path = tmp_path / "m.csv"
    m.to_csv(path)
    assert path.read_text().splitlines()[0] == "F,F,x"
    back = Measurement.from_csv(path, fs=20.0, inputs=["F"], periods=2)
    np.testing.assert_array_equal(back.u, m.u)
    np.testing.assert_array_equal(back.y, m.y)
    text = io.StringIO("f,a,b\n1,2,3\n4,5,6\n")
    only = Measurement.from_csv(text, fs=1.0, inputs="f", outputs=["b"])
    assert only.y[0, :, 0].tolist() == [3.0, 6.0]
    with pytest.raises(ValueError, match="no column"):
        Measurement.from_csv(io.StringIO("f,a\n1,2\n"), fs=1.0, inputs=["g"])


def test_csv_holds_one_realisation(record, tmp_path):
    with pytest.raises(ValueError, match="one realisation"):
        record.to_csv(tmp_path / "r.csv")


@pytest.mark.parametrize(("kwargs", "message"), [
    (dict(u=np.array([1.0, np.nan, 0, 0]), y=np.zeros(4)), "NaN"),
    (dict(u=np.zeros(4), y=np.zeros(5)), "same realisations and samples"),
    (dict(u=np.zeros((1, 1, 4, 1)), y=np.zeros(4)), "1-D"),
    (dict(u=np.zeros(6), y=np.zeros(6), periods=4), "does not divide"),
    (dict(u=np.zeros(4), y=np.zeros(4), periods=0), "positive integer"),
    (dict(u=np.zeros(4), y=np.zeros(4), fs=-1.0), "positive sampling rate"),
    (dict(u=np.zeros(4), y=np.zeros(4), quantity="strain"), "quantity"),
    (dict(u=np.zeros(4), y=np.zeros((4, 2)), output_names=["a"]), "one per column"),
    (dict(u=np.zeros(4), y=np.zeros((4, 2)), output_names=["a", "a"]), "unique"),
])
def test_bad_input_is_refused_with_the_reason(kwargs, message):
    kwargs = {"fs": 10.0} | kwargs
    with pytest.raises(ValueError, match=message):
        Measurement.from_arrays(**kwargs)


def test_unknown_channel_lists_the_valid_ones(record):
    with pytest.raises(ValueError, match=r"outputs are \['F', 'x2'\]"):
        record.output_index("x9")


@pytest.mark.parametrize("select", [
    lambda m: m.select(outputs=("x2", "x2")),
    lambda m: m.layout.select(outputs=("x2", "F", "x2")),
], ids=["measurement", "layout"])
def test_a_channel_chosen_twice_is_refused(record, select):
    with pytest.raises(ValueError, match=r"outputs \['x2'\] are chosen more than once"):
        select(record)
