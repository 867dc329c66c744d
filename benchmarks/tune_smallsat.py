"""Re-derive the tuned parameters of the SmallSat-like model (fnsi/smallsat_parameters.json).

Fits the physical parameters of :mod:`fnsi.smallsat` so that the model's first 11 modes
follow Table 1 of the paper and the two presets reach the regimes of Tables 3 and 8:
scipy.optimize.least_squares on the logarithms of the parameters (and of the force
unit, which sets the model's length unit), with residuals

- log-frequency errors / 1 % and log-damping errors / 10 % (steep beyond 15 %), each
  model mode matched to the Table 1 row of the same character (WMP families; the lowest
  panel rotations about X, Y, Z; then frequency order), the rows kept in order;
- a penalty keeping the twelfth mode above 55 Hz and bounds on the describing
  quantities of :func:`fnsi.smallsat.describe_mode` (CHARACTER);
- the linear RMS relative displacement at the eight stops under both presets (exact
  periodic frequency response) against SIGMA_TARGETS;
- a weak pull towards the starting design, so that parameters no mode sees stay put.

The matching by character is discontinuous, so the stored parameters were reached in
stages from START (the hand design of the WMP two-DOF rocking analysis): all
parameters; then ``--parameters`` subsets for the instrument panel and main structure
(SASSA, walls, panel aspect) and for the dashpots; then the force unit fixed at 20 N
(length unit 1 mm) by running both presets with the nonlinear simulation. Starting
from the stored file with ``--fix-force-unit --force-unit 20`` polishes them.

Usage::

    .venv/bin/python benchmarks/tune_smallsat.py [--start fnsi/smallsat_parameters.json]
        [--parameters a,b,...] [--force-unit 20 [--fix-force-unit]] [--write [PATH]]

Prints the tuned table beside Table 1, the force unit and the linear RMS at the stops;
with ``--write`` stores the parameters (default: beside fnsi/smallsat.py).
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

from fnsi import smallsat

TUNED = (
    "arm_radius", "wheel_height", "arm_tip_mass", "tangential_stiffness",
    "axial_damping", "radial_damping", "tangential_damping", "bracket_damping",
    "bracket_stiffness_x", "bracket_stiffness_y", "bracket_root_z", "bracket_middle_z",
    "bracket_tip_z",
    "wall_stiffness_x", "wall_stiffness_y", "wall_stiffness_z", "wall_top_stiffness",
    "wall_mass", "top_mass",
    "top_stiffness_x", "top_stiffness_y", "top_stiffness_z",
    "panel_corner_mass", "telescope_rim_mass", "telescope_height", "panel_aspect",
    "sassa_radial", "sassa_tangential", "sassa_axial",
    "mass_damping", "stiffness_damping",
)
"""Parameters the optimiser moves (log scale); the others keep their starting values."""

BOUNDS = {"arm_tip_mass": (0.3, 2.0), "wall_mass": (3.0, 30.0), "top_mass": (10.0, 60.0),
          "panel_corner_mass": (1.0, 10.0), "telescope_rim_mass": (0.5, 30.0),
          "arm_radius": (40.0, 150.0), "wheel_height": (40.0, 400.0),
          "telescope_height": (100.0, 900.0), "panel_half_width": (120.0, 450.0),
          "panel_aspect": (0.7, 1.4),
          "top_stiffness_y": (100.0, 1e6), "top_stiffness_z": (100.0, 1e6)}
"""Physical bounds [kg, mm, stiffness units] of parameters that must stay realistic."""

START = smallsat.SmallSatParameters(
    arm_radius=60.0, wheel_height=147.0, arm_tip_mass=1.06, cross_stiffness=1500.0,
    tangential_stiffness=2.0, axial_damping=2.8e-3, radial_damping=5.0e-4,
    tangential_damping=2.0e-3, bracket_node_mass=0.4, bracket_stiffness_x=150.0,
    bracket_stiffness_y=200.0, bracket_root_z=150.0, bracket_middle_z=10.0,
    bracket_tip_z=4.0, bracket_plate_stiffness=1.0, bracket_damping=1e-3,
    wall_mass=10.0, wall_stiffness_x=300.0, wall_stiffness_y=300.0,
    wall_stiffness_z=300.0, wall_top_stiffness=500.0, top_mass=30.0,
    top_stiffness_x=400.0, top_stiffness_y=3000.0, top_stiffness_z=3000.0,
    panel_half_width=300.0, panel_aspect=1.0, panel_corner_mass=3.0, telescope_rim_mass=12.0,
    telescope_height=650.0, panel_stiffness=10000.0, sassa_radial=500.0,
    sassa_tangential=42.0, sassa_axial=240.0, mass_damping=1.0, stiffness_damping=2.0e-4,
)
"""Hand design: WMP from the two-DOF rocking analysis (mass 8.5 kg, tip 1.06 kg,
wheel height / arm radius = 2.45), the rest from single-DOF estimates."""

WMP_FAMILIES = {"X": (0, 2), "Y": (1, 3), "Z": (4,), "RZ": (5,)}
"""Table 1 rows (0-based) of each WMP motion family, in ascending frequency."""
STRUCTURE_ROWS = (6, 7, 8, 9, 10)
"""Table 1 rows (0-based) of the instrument-panel and main-structure modes."""
PANEL_LEADERS = {6: "Y", 7: "X", 8: "RZ"}
"""Rows led by the lowest panel mode of a rigid-motion family (Y: about X, X: about Y)."""
SEPARATION_HZ = 55.0
MISSING = 30.0
"""Residual of a Table 1 mode that has no model mode of its character (in tolerance units)."""


def modes(params: smallsat.SmallSatParameters, count: int = 20):
    """Lowest ``count`` modes: frequencies [Hz], damping ratios [-], shapes (r, count)."""
    model = smallsat.smallsat_model(params)
    table = model.linear_modes()
    return (table.frequencies[:count], table.damping_ratios[:count],
            table.shapes[:count].T)


def match(params: smallsat.SmallSatParameters):
    """Model mode index for each Table 1 row (-1 if none) and the unmatched modes.

    A mode with more than half its kinetic energy in the WMP belongs to the WMP family
    with the largest rigid-body energy share, and pairs with the Table 1 rows of that
    family in ascending frequency. Of the other modes, the lowest rotation of the
    instrument panel about X, about Y and about Z pair with rows 7, 8 and 9, and the
    rest with rows 10 and 11 in ascending frequency.
    """
    _, _, shapes = modes(params)
    rows = np.full(11, -1)
    groups: dict[str, list[int]] = {}
    structure: list[int] = []
    panel: dict[int, dict[str, float]] = {}
    for k in range(shapes.shape[1]):
        d = smallsat.describe_mode(shapes[:, k], params)
        if d["wmp"] > 0.5:
            groups.setdefault(max(WMP_FAMILIES, key=lambda f: d[f"wmp_{f}"]), []).append(k)
        else:
            structure.append(k)
            panel[k] = d
    for row, family in PANEL_LEADERS.items():
        found = [k for k in structure if max(("X", "Y", "Z", "RZ"),
                                             key=lambda f, k=k: panel[k][f"panel_{f}"]) == family]
        if found:
            rows[row] = found[0]
            structure.remove(found[0])
    rest = [row for row in STRUCTURE_ROWS if row not in PANEL_LEADERS]
    extra = structure[len(rest):]
    rows[rest[:len(structure)]] = structure[:len(rest)]
    for family, table_rows in WMP_FAMILIES.items():
        found = groups.get(family, [])
        rows[list(table_rows)[:len(found)]] = found[:len(table_rows)]
        extra += found[len(table_rows):]
    return rows, sorted(extra)


def regime_sigmas(params: smallsat.SmallSatParameters, force_unit_n: float
                  ) -> dict[str, np.ndarray]:
    """Linear RMS relative displacement at the eight stops for both presets [length unit].

    Periodic excitation: Y = H U exactly on each line; a flat band-limited amplitude
    spectrum over 5-50 Hz with the preset's RMS force (converted to model force units)
    and the preset's period (30,000 samples at 2.5 kHz).
    """
    M, C, K = smallsat.assemble(params)
    lines = np.arange(5.0, 50.0, 1.0 / 12.0)
    w = 2j * np.pi * lines[:, None, None]
    dynamic = K[None] + w * C[None] + w**2 * M[None]
    elements = smallsat.wems_elements()
    dof = [smallsat.DOF_NAMES.index(e.dof) for e in elements]
    ref = [smallsat.DOF_NAMES.index(e.ref) for e in elements]
    out = {}
    for name, preset in smallsat.PRESETS.items():
        force = np.zeros(len(M))
        for channel, weight in preset.directions.items():
            force[smallsat.DOF_NAMES.index(channel)] = weight
        amplitude2 = 2.0 * (preset.rms_n / force_unit_n) ** 2 / lines.size
        x = np.linalg.solve(dynamic, np.broadcast_to(force, (lines.size, len(M)))[..., None])
        relative = x[:, dof, 0] - x[:, ref, 0]
        out[name] = np.sqrt(np.sum(np.abs(relative) ** 2, axis=0) * amplitude2 / 2.0)
    return out


SIGMA_TARGETS = {
    "single": np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.86, 0.0, 0.0]),
    "multi": np.array([1.53, 1.53, 1.45, 1.45, 1.18, 1.18, 1.07, 1.07]),
}
"""Linear RMS relative displacements [length unit] aimed at, in the order of
wems_elements (NC1-X, NC2-X, NC3-Y, NC4-Y, NC1-4 Z); 0 = no exceedance wanted. A
Gaussian of RMS s exceeds a gap g on a fraction 2 Q(g / s) of the samples (Q(g / s) for
a one-sided stop); the stops clip the peaks, so the simulated counts are 0.7-0.95 of
that, a factor calibrated per stop with the nonlinear simulation. Aimed counts: Table
3's 11,135 at NC2-Z, and Table 8's means per family (13,500 X, 14,200 Y, 26,000 Z)."""
QUIET_LIMIT = np.array([0.42, 0.42, 0.42, 0.42, 0.3, 0.3, 0.3, 0.3])
"""Largest linear RMS [length unit] of a stop that must stay open (gap / RMS > 4.7)."""


CHARACTER = (
    (4, "bracket_motion", ">", 0.15),   # 5: bends the bracket
    (7, "wmp_Z", ">", 0.55),            # 8: moves the WMP along Z
    (8, "panel_RZ", ">", 0.6),          # 9: rotation of the panel about Z
    (9, "main", ">", 0.01),             # 10: with the main structure
)
"""Bounds on :func:`fnsi.smallsat.describe_mode` quantities of Table 1 rows (0-based)."""


def character_residuals(rows: np.ndarray, shapes: np.ndarray,
                        params: smallsat.SmallSatParameters) -> np.ndarray:
    """Hinge residuals (log ratio / 5 %) of the CHARACTER bounds that are violated."""
    out = []
    for row, key, sense, bound in CHARACTER:
        if rows[row] < 0:
            out.append(MISSING)
            continue
        value = max(smallsat.describe_mode(shapes[:, rows[row]], params)[key], 1e-3)
        ratio = np.log(bound / value) if sense == ">" else np.log(value / bound)
        out.append(max(0.0, ratio) / 0.05)
    return np.array(out)


def residuals(x: np.ndarray, x0: np.ndarray, base: smallsat.SmallSatParameters,
              names: tuple[str, ...]) -> np.ndarray:
    """Scaled misfit to Table 1 and the regimes (see module docstring)."""
    params = with_vector(base, x[:-1], names)
    freq, zeta, shapes = modes(params)
    rows, extra = match(params)
    f_target = np.array([row[0] for row in smallsat.TABLE_1])
    z_target = np.array([row[1] for row in smallsat.TABLE_1]) / 100.0
    found = rows >= 0
    r_f = np.full(11, MISSING)
    r_z = np.full(11, MISSING)
    r_f[found] = np.log(freq[rows[found]] / f_target[found]) / 0.01
    log_z = np.log(zeta[rows[found]] / z_target[found])
    # 10 % scale, and steep beyond 15 % to keep every mode inside the 20 % tolerance.
    r_z[found] = log_z / 0.10 + np.sign(log_z) * np.maximum(0.0, np.abs(log_z) - 0.15) / 0.01
    lowest_extra = freq[extra[0]] if extra else SEPARATION_HZ
    r_sep = [max(0.0, np.log(SEPARATION_HZ / lowest_extra)) / 0.01]
    matched = np.where(found, freq[rows], f_target)
    # Table 1 order kept: each mode at least 0.1 % above the previous one.
    r_order = np.maximum(0.0, np.log(matched[:-1] * 1.001 / matched[1:])) / 0.001
    sigma = regime_sigmas(params, np.exp(x[-1]))
    r_regime = []
    for name, target in SIGMA_TARGETS.items():
        active = target > 0
        r_regime.append(np.log(sigma[name][active] / target[active]) / 0.10)
        r_regime.append(np.maximum(0.0, np.log(sigma[name][~active]
                                               / QUIET_LIMIT[~active])) / 0.05)
    return np.concatenate([r_f, r_z, r_sep, r_order, character_residuals(rows, shapes, params),
                           *r_regime, 0.3 * (x - x0)])


def with_vector(base: smallsat.SmallSatParameters, x: np.ndarray, names: tuple[str, ...]):
    """Parameters with ``names`` set to exp(x)."""
    return replace(base, **{k: float(np.exp(v)) for k, v in zip(names, x, strict=True)})


def tune(base: smallsat.SmallSatParameters, force_unit_n: float, max_nfev: int,
         names: tuple[str, ...] = TUNED, fixed_force_unit: bool = False,
         ) -> tuple[smallsat.SmallSatParameters, float]:
    """Least-squares fit of the parameters ``names`` and (unless fixed) the force unit [N]."""
    x0 = np.log([getattr(base, k) for k in names] + [force_unit_n])
    unit_range = (force_unit_n * (1 - 1e-9), force_unit_n * (1 + 1e-9)) if fixed_force_unit \
        else (1.0, 1000.0)
    lower = np.log([BOUNDS.get(k, (1e-12, 1e12))[0] for k in names] + [unit_range[0]])
    upper = np.log([BOUNDS.get(k, (1e-12, 1e12))[1] for k in names] + [unit_range[1]])
    solution = least_squares(residuals, np.clip(x0, lower, upper), bounds=(lower, upper),
                             args=(x0, base, names), max_nfev=max_nfev, diff_step=1e-4)
    return with_vector(base, solution.x[:-1], names), float(np.exp(solution.x[-1]))


def report(params: smallsat.SmallSatParameters) -> str:
    """Tuned modes beside Table 1, with the quantities that describe each."""
    freq, zeta, shapes = modes(params)
    rows, extra = match(params)
    lines = ["mode  f_paper  f_model  err%   z_paper  z_model  err%   Table 1 description"
             "                        | KE wmp/brk/pnl/main | motion"]
    for i, (f_p, z_p, text) in enumerate(smallsat.TABLE_1):
        k = rows[i]
        if k < 0:
            lines.append(f"{i + 1:4d}  {f_p:7.2f}  missing")
            continue
        d = smallsat.describe_mode(shapes[:, k], params)
        part = "wmp" if d["wmp"] > 0.5 else "panel"
        family = max(("X", "Y", "Z", "RZ"), key=lambda f, p=part: d[f"{p}_{f}"])
        motion = (f"WMP {family} phase {d['wmp_phase_' + family]:+.2f}"
                  if part == "wmp" and family in ("X", "Y") else
                  f"WMP {family}" if part == "wmp" else
                  f"IP {family} rot/transl {d['panel_rotation']:.2f} WMP-Z {d['wmp_Z']:.2f}")
        lines.append(
            f"{i + 1:4d}  {f_p:7.2f}  {freq[k]:7.2f}  {100 * (freq[k] / f_p - 1):+5.2f}  "
            f"{z_p:7.2f}  {100 * zeta[k]:7.2f}  {100 * (100 * zeta[k] / z_p - 1):+5.1f}  "
            f"{text[:45]:45s} | {d['wmp']:.2f} {d['bracket']:.2f} {d['panel']:.2f} "
            f"{d['main']:.2f} | {motion}")
    lines.append("next modes [Hz]: " + ", ".join(f"{freq[k]:.1f}" for k in extra[:4]))
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--start", type=Path, help="JSON parameters to start from")
    parser.add_argument("--max-nfev", type=int, default=300)
    parser.add_argument("--parameters", help="comma-separated subset of TUNED to move")
    parser.add_argument("--fix-force-unit", action="store_true",
                        help="keep the force unit (hence the length unit) as given")
    parser.add_argument("--force-unit", type=float, default=smallsat.FORCE_UNIT_N,
                        help="starting force unit [N]")
    parser.add_argument("--write", nargs="?", type=Path, const=smallsat.PARAMETERS_FILE,
                        help="store the tuned parameters (default: beside fnsi/smallsat.py)")
    args = parser.parse_args()
    base = (smallsat.SmallSatParameters.from_json(json.loads(args.start.read_text()))
            if args.start else START)
    t0 = time.perf_counter()
    names = tuple(args.parameters.split(",")) if args.parameters else TUNED
    tuned, force_unit = tune(base, args.force_unit, args.max_nfev, names, args.fix_force_unit)
    print(f"tuned in {time.perf_counter() - t0:.1f} s")
    print(report(tuned))
    print(f"force unit {force_unit:.3f} N = stiffness unit {smallsat.STIFFNESS_UNIT_N_PER_M:g} "
          f"N/m x length unit {force_unit / smallsat.STIFFNESS_UNIT_N_PER_M * 1e3:.4f} mm")
    for name, sigma in regime_sigmas(tuned, force_unit).items():
        print(f"linear RMS at the stops, {name}: " + " ".join(f"{v:.2f}" for v in sigma))
    if args.write:
        args.write.write_text(json.dumps(tuned.to_json(), indent=2) + "\n")
        print(f"written {args.write}")


if __name__ == "__main__":
    main()
