"""Export an identification to what other tools read: mode shapes as UFF 55, the whole
result as a MATLAB MAT file.

Both read the result document (``result.json``, :func:`fnsi.report.identification_report`),
so the CLI and the service write the same files and a kept ``result.json`` can be
exported again.

``modes.uff``
    One universal-file dataset 55 ("data at nodes") per identified mode: complex
    eigenvalue analysis (analysis type 3), displacement (specific data type 8), three
    translations per node. Outputs named ``<node>_<X|Y|Z>`` (the SmallSat's ``NC2w_Z``)
    share a node, one direction each; any other output is a node of its own, along
    direction 1. Nodes are numbered 1, 2, ... in the order their outputs first appear;
    ``result.mat`` holds their names (``node_names``) and the output each value comes
    from.
``result.mat``
    MAT v5: modes (``frequency_hz``, ``damping_ratio``, complex ``shapes`` outputs x
    modes, ``confirmed``), ``output_names``, ``order``, the model (``A``, ``B``, ``C``,
    ``D``, ``fs``, ``input_names``), the coefficients (``coefficient_names``,
    ``coefficient_mean_real``, NaN where not identifiable), the errors per output
    (``nrmse_percent_estimation`` and ``..._validation``, NaN where the model could not
    be simulated), ``warnings`` and the UFF node map.
"""

from __future__ import annotations

import io
import math
import re
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyuff
from scipy.io import savemat

_DIRECTION = re.compile(r"^(?P<node>.+)_(?P<axis>[XYZ])$", re.IGNORECASE)
_AXES = "XYZ"


def uff_nodes(output_names: Sequence[str]) -> tuple[list[str], list[tuple[int, int]]]:
    """Nodes of the UFF 55 file and where each output goes.

    Returns
    -------
    node_names : list of str
        Name of node k + 1.
    places : list of (int, int)
        Per output, its node index (0-based) and direction (0, 1, 2 for X, Y, Z).
    """
    node_names: list[str] = []
    places: list[tuple[int, int]] = []
    for name in output_names:
        match = _DIRECTION.match(name)
        node, axis = (match["node"], _AXES.index(match["axis"].upper())) if match else (name, 0)
        if node not in node_names:
            node_names.append(node)
        place = (node_names.index(node), axis)
        if place in places:
            raise ValueError(f"outputs {output_names[places.index(place)]!r} and {name!r} "
                             "fall on the same node and direction of the UFF file; rename one")
        places.append(place)
    return node_names, places


def modes_uff55(document: Mapping[str, Any]) -> bytes:
    """The identified modes of ``document`` (``result.json``) as UFF 55 datasets.

    Each mode k gives the complex eigenvalue lambda = -zeta omega + i omega sqrt(1 -
    zeta^2), omega = 2 pi f [rad/s], and its complex shape at the outputs (the unit of
    the outputs, scaled as identified).
    """
    modes = document["modes"]
    if not modes:
        raise ValueError("the result has no mode to export; identify with another order "
                         "or band first")
    names, places = uff_nodes(document["output_names"])
    datasets = []
    for number, mode in enumerate(modes, start=1):
        shape = np.array([re + 1j * im for re, im in mode["shape"]])
        r = np.zeros((3, len(names)), dtype=complex)
        for value, (node, axis) in zip(shape, places, strict=True):
            r[axis, node] = value
        f, zeta = mode["frequency_hz"], mode["damping_ratio"]
        omega = 2 * math.pi * f
        datasets.append(pyuff.prepare_55(
            model_type=1, id1="FNSI identified mode shapes",
            id2=f"mode {number}: {f:.6g} Hz, damping ratio {zeta:.4g}",
            id3="nodes: " + " ".join(f"{k + 1}={n}" for k, n in enumerate(names))[:72],
            id4="complex shapes at the outputs, unit of the outputs", id5="NONE",
            analysis_type=3, data_ch=2, spec_data_type=8, data_type=5, n_data_per_node=3,
            r1=r[0], r2=r[1], r3=r[2], node_nums=np.arange(1, len(names) + 1),
            load_case=1, mode_n=number,
            eig=complex(-zeta * omega, omega * math.sqrt(max(1 - zeta ** 2, 0.0))),
            modal_a=0j, modal_b=0j))
    with tempfile.TemporaryDirectory(prefix="fnsi-uff-") as folder:
        path = Path(folder) / "modes.uff"
        pyuff.UFF(str(path)).write_sets(datasets, mode="add")
        return path.read_bytes()


def result_mat(document: Mapping[str, Any]) -> bytes:
    """``document`` (``result.json``) as a MAT v5 file (see the module notes)."""
    modes = document["modes"]
    names, places = uff_nodes(document["output_names"])
    shapes = np.array([[re + 1j * im for re, im in m["shape"]] for m in modes],
                      dtype=complex).reshape(len(modes), len(places)).T
    contents: dict[str, Any] = {
        "frequency_hz": np.array([m["frequency_hz"] for m in modes], dtype=float),
        "damping_ratio": np.array([m["damping_ratio"] for m in modes], dtype=float),
        "shapes": shapes,
        "confirmed": np.array([np.nan if m["confirmed"] is None else float(m["confirmed"])
                               for m in modes]),
        "output_names": _cell(document["output_names"]),
        "order": document["order"],
        "coefficient_names": _cell([c["name"] for c in document["coefficients"]]),
        "coefficient_mean_real": _numbers([c.get("mean_real") for c in document["coefficients"]]),
        "warnings": _cell(document["warnings"]),
        "node_names": _cell(names),
        "node_of_output": np.array([node + 1 for node, _ in places], dtype=float),
        "direction_of_output": np.array([axis + 1 for _, axis in places], dtype=float),
    }
    model = document.get("model")
    if model is not None:
        contents |= {key: np.array(model[key], dtype=float) for key in ("A", "B", "C", "D")}
        contents |= {"fs": model["fs"], "input_names": _cell(model["input_names"])}
    for kind, errors in document.get("errors", {}).items():
        contents[f"nrmse_percent_{kind}"] = _numbers(
            [c["nrmse_percent"] for c in errors.get("channels", [])] if "channels" in errors
            else [None] * len(document["output_names"]))
    buffer = io.BytesIO()
    savemat(buffer, contents, do_compression=True, oned_as="column")
    return buffer.getvalue()


def _cell(texts: Sequence[str]) -> np.ndarray:
    """A MATLAB cell array of char rows."""
    cell = np.empty((len(texts), 1), dtype=object)
    for k, text in enumerate(texts):
        cell[k, 0] = str(text)
    return cell


def _numbers(values: Sequence[float | None]) -> np.ndarray:
    """Floats with NaN for missing (null) values."""
    return np.array([np.nan if v is None else v for v in values], dtype=float)


def export_files(document: Mapping[str, Any]) -> dict[str, bytes]:
    """``modes.uff`` (when there are modes) and ``result.mat`` of a result document."""
    files = {"modes.uff": modes_uff55(document)} if document["modes"] else {}
    return files | {"result.mat": result_mat(document)}
