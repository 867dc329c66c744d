"""SmallSat-like reduced structural model and the paper's two simulated tests (Section III, IV).

We do not have the 65,000-DOF finite-element model of the paper, so this module builds a
reduced lumped model of the same spacecraft from documented physical elements and tunes
it (``benchmarks/tune_smallsat.py``) so that its first 11 modes follow Table 1 and the
paper's two excitations reproduce the regimes of Tables 3 and 8.

Units
-----
The paper gives the WEMS stiffness curves in adimensional values (Table 2). The model
works in its own consistent units chosen so that those values are literally the
model's: length unit delta = :data:`LENGTH_UNIT_MM` mm, stiffness unit kappa =
:data:`STIFFNESS_UNIT_N_PER_M` N/m, time in s; hence force unit kappa delta =
:data:`FORCE_UNIT_N` N and mass unit kappa s^2 = :data:`MASS_UNIT_KG` kg. Clearances are
1.5 and 2 delta, linear slopes 8 and 2 kappa, added slopes beyond the stops 100 and 40
kappa, and an identification from the simulated measurement (forces in force units,
displacements in delta) finds mu = 100 and 40. kappa is set by the masses (8 kg wheel,
Table 1 frequencies, Table 2 slopes) and delta by the regimes of Tables 3 and 8 (the
paper's 100 N and 200 N must reach the clearances as often as in the paper).
Physical masses are stored in kg and lengths of the geometry in mm in
:class:`SmallSatParameters`; they are converted when the matrices are assembled.

Frame: Z is the inertia-wheel axis (the spacecraft axis); the WEMS bracket is a shelf
on the octagon wall at X < 0.

Structure (r = 48 DOFs, translations only, lumped diagonal mass matrix)
-----------------------------------------------------------------------
- WEMS mobile part (WMP), 8.5 kg: the 8 kg inertia wheel and its 0.5 kg metallic cross.
  The four arm tips carry the mobile-side connection nodes ``NC1w`` (+X), ``NC2w`` (-X),
  ``NC3w`` (+Y), ``NC4w`` (-Y) at ``arm_radius`` from the wheel axis, each with
  ``arm_tip_mass`` (its arm and a quarter of the wheel rim, which is how a model of
  translations carries the wheel's rotary inertia); the rest of the wheel is the hub
  node ``W`` on the axis, ``wheel_height`` above the plane of the cross. The cross is a
  pyramid truss of ten bars (hub to each tip, the tips' square and its two diagonals),
  practically rigid.
- WEMS elastomer: between each ``NCkw`` and the coincident bracket-side node ``NCkb``,
  three linear springs with lumped dashpots (the non-proportional damping): axial Z
  (slope 8, Table 2), radial (slope 2, Table 2: X for NC1-2, Y for NC3-4) and
  tangential (elastomer shear in the third direction).
- WEMS stops (nonlinear, :func:`wems_elements`): trilinear axial Z at NC1-4 (clearance
  1.5 on both sides, added slope 100) and bilinear radial (one stop, clearance 2, added
  slope 40) on the outward side of each arm: +X at NC1, -X at NC2, +Y at NC3, -Y at NC4.
- Bracket: the four ``NCkb`` nodes, each tied to the wall node ``WALL`` by three axis
  springs with dashpots (in-plane X and Y; bending in Z, one stiffness for NC2b on the
  wall side, one for NC3b and NC4b, one for NC1b on the far side) and to its
  neighbours by plate springs.
- Main structure: the octagon wall node ``WALL`` and the top floor node ``TOP``, each
  tied to the clamped base by axis springs (tube bending in X and Y, axial in Z), and to
  each other.
- Instrument panel (IP) and dummy telescope: the four panel corners ``IP1`` (+X+Y),
  ``IP2`` (-X+Y), ``IP3`` (-X-Y), ``IP4`` (+X-Y) and the 140 kg telescope, whose share
  ``telescope_rim_mass`` at each corner carries its rotary inertia and whose rest is the
  node ``TEL`` on the panel axis ``telescope_height`` above it; a practically rigid
  pyramid truss. It rests on the SASSA attenuators (at each corner three springs:
  radial from the panel axis, tangential, and axial):
  those of IP1 and IP4 on the top floor ``TOP``, those of IP2 and IP3 on the upper edge
  of the WEMS wall ``WALL`` (one lumped node for that wall panel), so that rotations of
  the panel about Y load the bracket axially (Table 1, mode 8).
- Structural damping: Rayleigh, ``mass_damping * M + stiffness_damping * K_s`` with
  K_s the stiffness of every element except the WEMS elastomer, plus dashpots
  (``bracket_damping``) in the bolted bracket-to-wall joint.

Measured DOFs are the 13 nodes of docs/design.md section 4 times X, Y, Z, named
``<node>_<axis>`` (``NC2w_Z``, ``IP3_X``), in this order: NC1w..NC4w, NC1b..NC4b, W,
IP1..IP4; the internal DOFs ``TEL_*``, ``TOP_*`` and ``WALL_*`` follow.

References
----------
J.P. Noël, G. Kerschen, "Nonparametric subspace identification of nonlinear structures -
Application to a spacecraft" (``paper/fnsi-smallsat-paper.md``), Section III (Tables 1,
2) and Section IV (Tables 3, 8).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import asdict, dataclass, fields, replace
from functools import cache
from pathlib import Path
from typing import Literal

import numpy as np

from fnsi.acquisition import Truth, acquire, check_timing
from fnsi.excitation import Excitation, excited_line_range, multisine, periodic_noise
from fnsi.measurement import Measurement, check_channels
from fnsi.nonlinear import NonlinearElement
from fnsi.structure import StructuralModel

AXES: tuple[str, ...] = ("X", "Y", "Z")
WMP_NODES: tuple[str, ...] = ("NC1w", "NC2w", "NC3w", "NC4w", "W")
BRACKET_NODES: tuple[str, ...] = ("NC1b", "NC2b", "NC3b", "NC4b")
PANEL_NODES: tuple[str, ...] = ("IP1", "IP2", "IP3", "IP4", "TEL")
MAIN_NODES: tuple[str, ...] = ("TOP", "WALL")
MEASURED_NODES: tuple[str, ...] = (
    "NC1w", "NC2w", "NC3w", "NC4w", "NC1b", "NC2b", "NC3b", "NC4b",
    "W", "IP1", "IP2", "IP3", "IP4",
)
INTERNAL_NODES: tuple[str, ...] = ("TEL", "TOP", "WALL")
NODES: tuple[str, ...] = MEASURED_NODES + INTERNAL_NODES
SUBSTRUCTURES: dict[str, tuple[str, ...]] = {
    "wmp": WMP_NODES, "bracket": BRACKET_NODES, "panel": PANEL_NODES, "main": MAIN_NODES,
}
"""Nodes of each substructure: WEMS mobile part, bracket, instrument panel with the
telescope, main structure (used to describe mode shapes, Table 1)."""

MEASURED_DOFS: tuple[str, ...] = tuple(f"{n}_{a}" for n in MEASURED_NODES for a in AXES)
DOF_NAMES: tuple[str, ...] = tuple(f"{n}_{a}" for n in NODES for a in AXES)

BRACKET_TIP = "NC2b_Z"
"""Channel whose RMS response sets the measurement-noise level: the paper's "bracket
tip", taken as the bracket side of the excited connection NC2 (axial)."""

STIFFNESS_UNIT_N_PER_M = 2.0e4
"""One model stiffness unit in N/m (kappa)."""
LENGTH_UNIT_MM = 1.0
"""One model length unit in mm (delta): DOFs, clearances and outputs are in delta."""
FORCE_UNIT_N = STIFFNESS_UNIT_N_PER_M * LENGTH_UNIT_MM * 1e-3
"""One model force unit in N (kappa * delta): inputs of simulated measurements."""
MASS_UNIT_KG = STIFFNESS_UNIT_N_PER_M
"""One model mass unit (force unit s^2 / length unit) in kg."""
FORCE_UNIT = f"{FORCE_UNIT_N:g} N"
"""Unit label of the simulated inputs ("20 N"): coefficients read in 20 N per mm^p."""
LENGTH_UNIT = "mm" if LENGTH_UNIT_MM == 1 else f"{LENGTH_UNIT_MM:g} mm"
"""Unit label of the simulated displacements."""
OUTPUT_UNITS = {"displacement": LENGTH_UNIT, "velocity": f"{LENGTH_UNIT}/s",
                "acceleration": f"{LENGTH_UNIT}/s^2"}
"""Unit label of the simulated outputs of each quantity."""

WMP_MASS_KG = 8.5
TELESCOPE_MASS_KG = 140.0
AXIAL_GAP, AXIAL_SLOPE, AXIAL_ADDED = 1.5, 8.0, 100.0     # Table 2, length / stiffness units
LATERAL_GAP, LATERAL_SLOPE, LATERAL_ADDED = 2.0, 2.0, 40.0  # Table 2, length / stiffness units

WEMS_CENTRE = np.array([-300.0, 0.0, 400.0])   # mm, WEMS cross centre
WALL_POSITION = np.array([-500.0, 0.0, 400.0])  # mm, bracket root on the octagon wall
TOP_POSITION = np.array([0.0, 0.0, 1200.0])     # mm, top floor centre
PANEL_HEIGHT = 1300.0                           # mm, instrument-panel plane

ARM_DIRECTIONS: dict[str, np.ndarray] = {
    "NC1": np.array([1.0, 0.0, 0.0]), "NC2": np.array([-1.0, 0.0, 0.0]),
    "NC3": np.array([0.0, 1.0, 0.0]), "NC4": np.array([0.0, -1.0, 0.0]),
}
"""Outward radial direction of each WEMS arm (NC1-2 radial X, NC3-4 radial Y)."""
CORNER_SIGNS: dict[str, tuple[float, float]] = {
    "IP1": (1.0, 1.0), "IP2": (-1.0, 1.0), "IP3": (-1.0, -1.0), "IP4": (1.0, -1.0),
}

SASSA_SUPPORTS: dict[str, str] = {"IP1": "TOP", "IP2": "WALL", "IP3": "WALL", "IP4": "TOP"}

TABLE_1: tuple[tuple[float, float, str], ...] = (
    (10.67, 5.34, "Concave motion of the WEMS mobile part (WMP) along X"),
    (11.01, 5.58, "Symmetric to mode 1 along Y"),
    (28.26, 9.79, "Convex motion of the WMP along X"),
    (28.41, 10.62, "Symmetric to mode 3 along Y"),
    (30.11, 7.03, "Bracket bending and in-phase motion of the WMP along Z"),
    (30.52, 15.54, "Rotation of the WMP around Z"),
    (31.59, 2.07, "Rotation of the instrument panel (IP)"),
    (32.62, 2.25, "Rotation of the IP perpendicularly to mode 7 and motion of the WMP along Z"),
    (37.47, 2.27, "Rotation of the IP similarly to mode 8 and rotation around Z"),
    (38.26, 2.33, "Main structure bending and in-plane motion of the IP in phase"),
    (43.31, 2.51, "Rotation of the IP similarly to mode 8"),
)
"""Paper Table 1: natural frequency [Hz], damping ratio [%], description of modes 1-11."""

TABLE_3: dict[str, int] = {"NC1_X": 0, "NC2_X": 0, "NC3_Y": 0, "NC4_Y": 0,
                           "NC1_Z": 0, "NC2_Z": 11135, "NC3_Z": 0, "NC4_Z": 0}
"""Paper Table 3: clearance exceedances of the single-input test over the 6 kept periods."""
TABLE_8: dict[str, int] = {"NC1_X": 13453, "NC2_X": 13001, "NC3_Y": 13600, "NC4_Y": 14803,
                           "NC1_Z": 28043, "NC2_Z": 21218, "NC3_Z": 25854, "NC4_Z": 31661}
"""Paper Table 8: clearance exceedances of the multi-nonlinearity test."""


@dataclass(frozen=True)
class Preset:
    """One of the paper's simulated tests (Section IV).

    Attributes
    ----------
    directions : dict
        Force direction: weight of the input force on each excited DOF (unit norm).
    rms_n : float
        RMS of the input force [N].
    band : tuple of float
        Excited band [Hz] of the periodic random noise.
    discard_periods : int
        Leading periods that hold the transient from rest, left out of the noise
        reference and of the exceedance counts (the paper keeps the last 6 of 8).
    """

    directions: dict[str, float]
    rms_n: float
    band: tuple[float, float] = (5.0, 50.0)
    discard_periods: int = 2


PRESETS: dict[str, Preset] = {
    "single": Preset({"NC2w_Z": 1.0}, 100.0),
    "multi": Preset({"W_X": 1.0 / np.sqrt(2.0), "W_Y": 1.0 / np.sqrt(2.0)}, 200.0),
}
"""Paper IV.A (100 N RMS axial at NC2w, impacts at NC2-Z only) and IV.C (200 N RMS at
the wheel along the X-Y diagonal, all eight stops active)."""

PARAMETERS_FILE = Path(__file__).with_name("smallsat_parameters.json")


@dataclass(frozen=True)
class SmallSatParameters:
    """Physical parameters of the reduced SmallSat model (lengths mm, masses kg,
    stiffness in stiffness units, damping in force units s / length unit; see the module
    docstring for the units and each element).

    The tuned values live in ``fnsi/smallsat_parameters.json`` and are re-derived by
    ``benchmarks/tune_smallsat.py``.
    """

    arm_radius: float              # mm, wheel axis to each NC
    wheel_height: float            # mm, wheel centre above the cross plane
    arm_tip_mass: float            # kg, arm and wheel-rim share at each NCkw
    cross_stiffness: float         # each bar of the WMP truss
    tangential_stiffness: float    # elastomer shear in the non-stop lateral axis
    axial_damping: float           # elastomer dashpot along Z at each NC
    radial_damping: float          # elastomer dashpot along the stop axis
    tangential_damping: float      # elastomer dashpot in the third direction
    bracket_node_mass: float       # kg, bracket share at each NCkb
    bracket_stiffness_x: float     # NCkb to wall, X
    bracket_stiffness_y: float     # NCkb to wall, Y
    bracket_root_z: float          # NC2b (next to the wall) to wall, Z
    bracket_middle_z: float        # NC3b and NC4b to wall, Z (bracket bending)
    bracket_tip_z: float           # NC1b (bracket tip) to wall, Z
    bracket_plate_stiffness: float  # between neighbouring NCkb, each axis
    bracket_damping: float         # dashpot of the bracket-to-wall joint, each axis
    wall_mass: float               # kg
    wall_stiffness_x: float        # wall node to the clamped base, X (tube bending)
    wall_stiffness_y: float        # wall node to the clamped base, Y
    wall_stiffness_z: float        # wall node to the clamped base, Z
    wall_top_stiffness: float      # wall node to top floor, each axis
    top_mass: float                # kg, octagon and top floor share at the top node
    top_stiffness_x: float         # tube bending along X
    top_stiffness_y: float         # tube bending along Y
    top_stiffness_z: float         # tube axial
    panel_half_width: float        # mm, w: IP corners at (+-w a, +-w / a) from the panel axis
    panel_aspect: float            # a: aspect of the panel (X half-width over w)
    panel_corner_mass: float       # kg, panel share at each corner
    telescope_rim_mass: float      # kg, telescope share at each corner (rotary inertia)
    telescope_height: float        # mm, telescope centre of mass above the panel
    panel_stiffness: float         # each bar of the panel-telescope truss
    sassa_radial: float            # attenuator at each corner, radial from the panel axis
    sassa_tangential: float        # attenuator at each corner, in-plane tangential
    sassa_axial: float             # attenuator at each corner, Z
    mass_damping: float            # 1/s, Rayleigh alpha
    stiffness_damping: float       # s, Rayleigh beta (structure, not the elastomer)

    def to_json(self) -> dict[str, float]:
        """Parameters as a flat JSON object."""
        return asdict(self)

    @classmethod
    def from_json(cls, data: dict[str, float]) -> SmallSatParameters:
        """Parameters from :meth:`to_json`; ValueError naming missing or unknown keys."""
        names = {f.name for f in fields(cls)}
        missing, unknown = names - set(data), set(data) - names
        if missing or unknown:
            raise ValueError(
                f"SmallSat parameters must have exactly the keys {sorted(names)}; "
                f"missing {sorted(missing)}, unknown {sorted(unknown)}"
            )
        return cls(**{k: float(v) for k, v in data.items()})


@cache
def tuned_parameters() -> SmallSatParameters:
    """The tuned parameters stored beside this module (``smallsat_parameters.json``)."""
    return SmallSatParameters.from_json(json.loads(PARAMETERS_FILE.read_text()))


def node_positions(params: SmallSatParameters) -> dict[str, np.ndarray]:
    """Position [mm] of every node of the model (undeformed geometry)."""
    pos = {}
    for nc, d in ARM_DIRECTIONS.items():
        pos[f"{nc}w"] = WEMS_CENTRE + params.arm_radius * d
        pos[f"{nc}b"] = pos[f"{nc}w"].copy()
    pos["W"] = WEMS_CENTRE + np.array([0.0, 0.0, params.wheel_height])
    wx = params.panel_half_width * params.panel_aspect
    wy = params.panel_half_width / params.panel_aspect
    for corner, (sx, sy) in CORNER_SIGNS.items():
        pos[corner] = np.array([sx * wx, sy * wy, PANEL_HEIGHT])
    pos["TEL"] = np.array([0.0, 0.0, PANEL_HEIGHT + params.telescope_height])
    pos["TOP"] = TOP_POSITION.copy()
    pos["WALL"] = WALL_POSITION.copy()
    return pos


def _node_masses(params: SmallSatParameters) -> dict[str, float]:
    """Lumped mass [kg] of every node."""
    masses = {f"{nc}w": params.arm_tip_mass for nc in ARM_DIRECTIONS}
    masses |= {f"{nc}b": params.bracket_node_mass for nc in ARM_DIRECTIONS}
    masses |= {c: params.panel_corner_mass + params.telescope_rim_mass for c in CORNER_SIGNS}
    masses |= {"W": WMP_MASS_KG - 4.0 * params.arm_tip_mass,
               "TEL": TELESCOPE_MASS_KG - 4.0 * params.telescope_rim_mass,
               "TOP": params.top_mass, "WALL": params.wall_mass}
    return masses


class _Assembler:
    """Adds two-node (or node-to-base) line elements to a global (r, r) matrix."""

    def __init__(self) -> None:
        self.matrix = np.zeros((len(DOF_NAMES), len(DOF_NAMES)))

    def line(self, value: float, direction: np.ndarray, node: str, ref: str | None) -> None:
        """Spring or dashpot ``value`` acting along unit ``direction`` between two nodes."""
        e = np.asarray(direction, dtype=float) / np.linalg.norm(direction)
        block = value * np.outer(e, e)
        i = 3 * NODES.index(node)
        self.matrix[i:i + 3, i:i + 3] += block
        if ref is not None:
            j = 3 * NODES.index(ref)
            self.matrix[j:j + 3, j:j + 3] += block
            self.matrix[i:i + 3, j:j + 3] -= block
            self.matrix[j:j + 3, i:i + 3] -= block

    def axes(self, values: tuple[float, float, float], node: str, ref: str | None) -> None:
        """Three springs or dashpots along X, Y, Z."""
        for value, direction in zip(values, np.eye(3), strict=True):
            self.line(value, direction, node, ref)

    def truss(self, value: float, pairs, pos: dict[str, np.ndarray]) -> None:
        """Bars of axial stiffness ``value`` between the given node pairs."""
        for a, b in pairs:
            self.line(value, pos[b] - pos[a], a, b)


def _truss_pairs(apex: str, corners: tuple[str, ...]) -> list[tuple[str, str]]:
    """Bars of a pyramid: apex to each corner, the corners' ring and its two diagonals."""
    ring = [(corners[k], corners[(k + 1) % 4]) for k in range(4)]
    return [(apex, c) for c in corners] + ring + [(corners[0], corners[2]),
                                                   (corners[1], corners[3])]


def _structure_stiffness(p: SmallSatParameters, pos: dict[str, np.ndarray]) -> np.ndarray:
    """Stiffness of everything but the WEMS elastomer (it bears the Rayleigh damping)."""
    k = _Assembler()
    k.truss(p.cross_stiffness, _truss_pairs("W", ("NC1w", "NC3w", "NC2w", "NC4w")), pos)
    bracket = ("NC1b", "NC3b", "NC2b", "NC4b")
    bending = {"NC1b": p.bracket_tip_z, "NC2b": p.bracket_root_z,
               "NC3b": p.bracket_middle_z, "NC4b": p.bracket_middle_z}
    for node in bracket:
        k.axes((p.bracket_stiffness_x, p.bracket_stiffness_y, bending[node]), node, "WALL")
    for a, b in ((bracket[n], bracket[(n + 1) % 4]) for n in range(4)):
        k.axes((p.bracket_plate_stiffness,) * 3, a, b)
    k.axes((p.wall_stiffness_x, p.wall_stiffness_y, p.wall_stiffness_z), "WALL", None)
    k.axes((p.wall_top_stiffness,) * 3, "WALL", "TOP")
    k.axes((p.top_stiffness_x, p.top_stiffness_y, p.top_stiffness_z), "TOP", None)
    k.truss(p.panel_stiffness, _truss_pairs("TEL", ("IP1", "IP2", "IP3", "IP4")), pos)
    for corner, support in SASSA_SUPPORTS.items():
        sx, sy = CORNER_SIGNS[corner]
        k.line(p.sassa_radial, np.array([sx, sy, 0.0]), corner, support)
        k.line(p.sassa_tangential, np.array([-sy, sx, 0.0]), corner, support)
        k.line(p.sassa_axial, np.array([0.0, 0.0, 1.0]), corner, support)
    return k.matrix


def _bracket_joint(damping: float) -> np.ndarray:
    """Dashpots [damping units] of the bracket-to-wall joint along X, Y, Z at each NCkb."""
    c = _Assembler()
    for node in BRACKET_NODES:
        c.axes((damping,) * 3, node, "WALL")
    return c.matrix


def _elastomer(p: SmallSatParameters, values: tuple[float, float, float]) -> np.ndarray:
    """WEMS elastomer matrix from (axial, radial, tangential) values at each NC."""
    e = _Assembler()
    axial, radial, tangential = values
    for nc, d in ARM_DIRECTIONS.items():
        radial_axis = np.abs(d)
        tangential_axis = np.array([radial_axis[1], radial_axis[0], 0.0])
        e.line(axial, np.array([0.0, 0.0, 1.0]), f"{nc}w", f"{nc}b")
        e.line(radial, radial_axis, f"{nc}w", f"{nc}b")
        e.line(tangential, tangential_axis, f"{nc}w", f"{nc}b")
    return e.matrix


def assemble(params: SmallSatParameters) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mass, damping and stiffness matrices of the model in model units (module docstring).

    Parameters
    ----------
    params : SmallSatParameters
        Physical parameters.

    Returns
    -------
    M, C, K : ndarray, shape (r, r)
        Mass [force unit s^2 / length unit] (diagonal), viscous damping [force unit s /
        length unit] and stiffness [stiffness unit]
        matrices, DOFs ordered as :data:`DOF_NAMES`.
    """
    pos = node_positions(params)
    masses = _node_masses(params)
    M = np.diag(np.repeat([masses[n] / MASS_UNIT_KG for n in NODES], 3))
    K_s = _structure_stiffness(params, pos)
    K = K_s + _elastomer(params, (AXIAL_SLOPE, LATERAL_SLOPE, params.tangential_stiffness))
    C = (params.mass_damping * M + params.stiffness_damping * K_s
         + _elastomer(params, (params.axial_damping, params.radial_damping,
                               params.tangential_damping))
         + _bracket_joint(params.bracket_damping))
    return M, C, K


def _rigid_fit(shape: np.ndarray, nodes: tuple[str, ...], centre: np.ndarray,
               pos: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares rigid motion u = t + theta x (p - centre) of ``nodes``.

    Returns the translation t (3,), rotation theta (3,) [rad per mm of mode amplitude]
    and the (3 n, 6) rigid-body basis, columns t_x, t_y, t_z, theta_x, theta_y, theta_z.
    """
    rows = []
    for n in nodes:
        x, y, z = pos[n] - centre
        rows.append(np.array([[1, 0, 0, 0, z, -y], [0, 1, 0, -z, 0, x], [0, 0, 1, y, -x, 0]]))
    basis = np.vstack(rows).astype(float)
    idx = [DOF_NAMES.index(f"{n}_{a}") for n in nodes for a in AXES]
    coef = np.linalg.lstsq(basis, shape[idx], rcond=None)[0]
    return coef[:3], coef[3:], basis


def describe_mode(shape: np.ndarray, params: SmallSatParameters | None = None
                  ) -> dict[str, float]:
    """Quantities that tell which motion of Table 1 a mode shape is.

    Parameters
    ----------
    shape : ndarray, shape (r,), real or complex
        Mode shape over :data:`DOF_NAMES` (any scaling).
    params : SmallSatParameters, optional
        Model parameters (default: the tuned ones).

    Returns
    -------
    dict
        ``wmp``, ``bracket``, ``panel``, ``main``: share of the kinetic energy in each
        substructure of :data:`SUBSTRUCTURES` (sum 1). ``wmp_X``, ``wmp_Y``, ``wmp_Z``,
        ``wmp_RZ``: shares of the WMP's rigid-body kinetic energy in its lateral X
        family (translation X with rocking about Y), lateral Y family, axial translation
        and rotation about the wheel axis. ``wmp_phase_X``, ``wmp_phase_Y``: cosine of
        the phase between the hub's and the cross centre's lateral motion: > 0 when
        they move together (concave motion, the WMP swings about a point below the
        cross), < 0 when opposed (convex motion, it rocks about a point between cross
        and wheel). ``panel_X``, ``panel_Y``, ``panel_Z``, ``panel_RZ``: the same shares
        for the rigid motion of the instrument panel with the telescope.
        ``panel_rotation``: amplitude at the panel corners of its rotation about X and Y
        over that of its in-plane translation (> 1: a rotation of the IP, < 1: an
        in-plane motion). ``panel_top_phase``: cosine of the phase between the panel's
        and the top floor's in-plane translations (> 0: in phase). ``bracket_motion``:
        RMS displacement of the bracket-side NC nodes over that of the mobile-side ones
        (the bracket's share in a WMP mode).
    """
    params = tuned_parameters() if params is None else params
    pos = node_positions(params)
    masses = np.repeat([_node_masses(params)[n] for n in NODES], 3)
    shape = np.asarray(shape)
    energy = masses * np.abs(shape) ** 2
    out = {sub: float(sum(energy[3 * NODES.index(n):3 * NODES.index(n) + 3].sum()
                          for n in nodes) / energy.sum())
           for sub, nodes in SUBSTRUCTURES.items()}
    t, theta, basis = _rigid_fit(shape, WMP_NODES, WEMS_CENTRE, pos)
    wmp_masses = masses[[DOF_NAMES.index(f"{n}_{a}") for n in WMP_NODES for a in AXES]]
    coef = np.concatenate([t, theta])
    families = {"X": [0, 4], "Y": [1, 3], "Z": [2], "RZ": [5]}
    fam = {k: float(wmp_masses @ np.abs(basis[:, c] @ coef[c]) ** 2)
           for k, c in families.items()}
    out |= {f"wmp_{k}": v / sum(fam.values()) for k, v in fam.items()}
    hub = t + np.cross(theta, pos["W"] - WEMS_CENTRE)
    for axis, i in (("X", 0), ("Y", 1)):
        out[f"wmp_phase_{axis}"] = float(np.real(hub[i] * np.conj(t[i]))
                                         / (abs(hub[i]) * abs(t[i]) + 1e-300))
    t, theta, basis = _rigid_fit(shape, PANEL_NODES, np.array([0.0, 0.0, PANEL_HEIGHT]),
                                 pos)
    panel_masses = masses[[DOF_NAMES.index(f"{n}_{a}") for n in PANEL_NODES for a in AXES]]
    coef = np.concatenate([t, theta])
    fam = {k: float(panel_masses @ np.abs(basis[:, c] @ coef[c]) ** 2)
           for k, c in families.items()}
    out |= {f"panel_{k}": v / sum(fam.values()) for k, v in fam.items()}
    wx = params.panel_half_width * params.panel_aspect
    wy = params.panel_half_width / params.panel_aspect
    out["panel_rotation"] = float(np.hypot(abs(theta[0]) * wy, abs(theta[1]) * wx)
                                  / (np.hypot(abs(t[0]), abs(t[1])) + 1e-300))
    top = shape[[DOF_NAMES.index(f"TOP_{a}") for a in ("X", "Y")]]
    out["panel_top_phase"] = float(np.real(np.vdot(top, t[:2]))
                                   / (np.linalg.norm(top) * np.linalg.norm(t[:2]) + 1e-300))
    rms = {sub: np.sqrt(np.mean(np.abs(shape[[DOF_NAMES.index(f"{n}_{a}") for n in nodes
                                               for a in AXES]]) ** 2))
           for sub, nodes in (("wmp", WMP_NODES[:4]), ("bracket", BRACKET_NODES))}
    out["bracket_motion"] = float(rms["bracket"] / rms["wmp"])
    return out


def wems_elements() -> tuple[NonlinearElement, ...]:
    """The eight WEMS stops of Table 2 as clearance elements with their true coefficients.

    Axial Z at NC1-4: clearance 1.5 on both sides, added slope 100 beyond it (trilinear
    with the elastomer's 8). Radial at NC1-2 (X) and NC3-4 (Y): one stop on the outward
    side of each arm, clearance 2, added slope 40 (bilinear with the elastomer's 2).
    Model length and stiffness units; relative displacement = mobile - bracket side.
    """
    elements = []
    for nc, d in ARM_DIRECTIONS.items():
        axis = "X" if d[0] else "Y"
        side = "positive" if d.sum() > 0 else "negative"
        elements.append(NonlinearElement(
            "clearance", f"{nc}w_{axis}", f"{nc}b_{axis}", side=side,
            **{f"gap_{side}": LATERAL_GAP}, coefficients=(LATERAL_ADDED,)))
    elements += [NonlinearElement("clearance", f"{nc}w_Z", f"{nc}b_Z", gap=AXIAL_GAP,
                                  coefficients=(AXIAL_ADDED,)) for nc in ARM_DIRECTIONS]
    return tuple(elements)


def smallsat_model(params: SmallSatParameters | None = None) -> StructuralModel:
    """The SmallSat-like structural model with its eight WEMS stops (model units).

    Parameters
    ----------
    params : SmallSatParameters, optional
        Physical parameters; default the tuned ones (:func:`tuned_parameters`).

    Returns
    -------
    StructuralModel
        r = 48 DOFs named :data:`DOF_NAMES` (the 39 measured ones first), mass
        damping and stiffness matrices in model units (see :func:`assemble`), and the
        elements of :func:`wems_elements`.

    Examples
    --------
    >>> model = smallsat_model()
    >>> model.n_dofs, model.dof_names[5], len(model.elements)
    (48, 'NC2w_Z', 8)
    """
    M, C, K = assemble(tuned_parameters() if params is None else params)
    return StructuralModel(M, C, K, DOF_NAMES, wems_elements())


def check_preset(name: str, *, periods: int, samples_per_period: int,
                 outputs: tuple[str, ...] | None, fs: float, fs_int: float) -> Preset:
    """The preset called ``name``, after checking that :func:`simulate_preset` can run it
    with these arguments; parameters as there.

    Cheap (no simulation): a service refuses with it, at submission, a run that could
    only fail (too few periods after the preset's transient, unknown or repeated outputs,
    rates or a period that cannot carry the preset's band).

    Returns
    -------
    Preset

    Raises
    ------
    ValueError
        Naming the preset and what to change.

    Examples
    --------
    >>> check_preset("single", periods=2, samples_per_period=2500, outputs=None,
    ...              fs=2500.0, fs_int=20000.0)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ValueError: preset 'single': periods=2 leaves no period after the 2 transient ...
    """
    if name not in PRESETS:
        raise ValueError(f"unknown SmallSat preset {name!r}; use one of {list(PRESETS)}")
    preset = PRESETS[name]
    try:
        check_timing(fs, fs_int, samples_per_period, periods, preset.discard_periods)
        excited_line_range(samples_per_period, fs, preset.band)
        check_channels(outputs or (), DOF_NAMES, "output")
    except ValueError as err:
        raise ValueError(f"preset {name!r}: {err}") from None
    return preset


def simulate_preset(name: Literal["single", "multi"], *, periods: int = 8,
                    samples_per_period: int = 30000, rms: float | None = None,
                    seed: int = 0, noise_percent: float = 0.5,
                    outputs: tuple[str, ...] | None = None,
                    quantity: str = "displacement", fs: float = 2500.0,
                    fs_int: float = 20000.0,
                    parameters: SmallSatParameters | None = None,
                    signal: Literal["periodic-noise", "random-odd"] = "periodic-noise",
                    progress: Callable[[float, str], None] | None = None,
                    ) -> tuple[Measurement, Truth]:
    """Simulate one of the paper's SmallSat tests (Section IV.A or IV.C).

    Periodic Gaussian noise band-limited to 5-50 Hz, repeated ``periods`` times, drives
    :func:`smallsat_model` from rest; nonlinear Newmark integration at ``fs_int``,
    anti-aliased decimation to ``fs`` and band-limited (0-100 Hz) output noise at
    ``noise_percent`` % of the RMS response of the bracket tip :data:`BRACKET_TIP`
    (:func:`fnsi.acquisition.acquire`, which also simulates user-defined structures).

    Parameters
    ----------
    name : {"single", "multi"}
        ``"single"``: 100 N RMS axial at ``NC2w_Z`` (Table 3 regime, only NC2-Z
        impacts). ``"multi"``: 200 N RMS at the wheel ``W`` along the X-Y diagonal, the
        force split equally on ``W_X`` and ``W_Y`` (Table 8 regime, all eight stops).
    periods : int
        Periods simulated and recorded, more than the preset's ``discard_periods`` (the
        paper keeps the last 6 of 8).
    samples_per_period : int
        Samples per period at ``fs`` (30,000 = 12 s: lines every 1/12 Hz).
    rms : float, optional
        Force RMS [N]; default the paper's (100 or 200 N).
    seed : int
        Seed of the excitation and of the measurement noise.
    noise_percent : float
        Output noise RMS in % of the bracket tip's RMS response.
    outputs : tuple of str, optional
        Measured DOFs; default the 39 of :data:`MEASURED_DOFS`.
    quantity : {"displacement", "velocity", "acceleration"}
        What the outputs measure.
    fs, fs_int : float
        Measurement and integration sampling rates [Hz].
    parameters : SmallSatParameters, optional
        A variant of the structure (sensitivity studies); default the tuned parameters.
    signal : {"periodic-noise", "random-odd"}
        The paper's periodic noise, or a random-odd multisine of the same RMS (odd lines
        only, one left out in four): its non-excited lines tell odd nonlinear distortions
        from even ones (:mod:`fnsi.distortion`).
    progress : callable(fraction, message), optional
        Progress callback of the simulation; may raise to cancel.

    Returns
    -------
    Measurement
        Input in model force units (:data:`FORCE_UNIT_N` N), outputs in model length
        units (:data:`LENGTH_UNIT_MM` mm, per s for velocity, per s^2 for acceleration),
        both declared as the channels' units (:data:`FORCE_UNIT`, :data:`OUTPUT_UNITS`).
    Truth
        Linear modes at the outputs, the eight WEMS elements with their true
        coefficients and the clearance exceedances over the kept periods.

    Examples
    --------
    >>> m, truth = simulate_preset("single", periods=3, samples_per_period=2500,
    ...                            outputs=("NC2w_Z", "NC2b_Z"))   # doctest: +SKIP
    >>> m.input_names, m.output_names, m.y.shape                   # doctest: +SKIP
    (('F_NC2w_Z',), ('NC2w_Z', 'NC2b_Z'), (1, 7500, 2))
    """
    preset = check_preset(name, periods=periods, samples_per_period=samples_per_period,
                          outputs=outputs, fs=fs, fs_int=fs_int)
    rms_n = preset.rms_n if rms is None else float(rms)
    outputs = MEASURED_DOFS if outputs is None else tuple(outputs)
    excitation_seed, noise_seed = np.random.SeedSequence(seed).generate_state(2)
    if signal not in ("periodic-noise", "random-odd"):
        raise ValueError(f"signal must be 'periodic-noise' or 'random-odd'; got {signal!r}")
    make = periodic_noise if signal == "periodic-noise" else (
        lambda *a, **k: multisine(*a, lines="odd", detection=4, **k))
    force = make(samples_per_period, fs, preset.band, rms_n / FORCE_UNIT_N,
                 seed=int(excitation_seed))
    excitation = Excitation.along(force, fs, preset.directions)
    simulated = outputs if BRACKET_TIP in outputs else (*outputs, BRACKET_TIP)
    measurement, truth = acquire(
        smallsat_model(parameters), excitation, fs=fs, fs_int=fs_int, periods=periods,
        outputs=simulated, quantity=quantity, noise_percent=noise_percent,
        noise_reference=BRACKET_TIP, discard_periods=preset.discard_periods,
        seed=int(noise_seed), progress=progress)
    measurement = replace(measurement, input_units=(FORCE_UNIT,),
                          output_units=(OUTPUT_UNITS[quantity],))
    if simulated == outputs:
        return measurement, truth
    modal = replace(truth.modal, shapes=truth.modal.shapes[:, :-1], output_names=outputs)
    return measurement.select(outputs=outputs), replace(truth, modal=modal)
