"""Every figure function returns a non-trivial PNG without touching pyplot state."""

from __future__ import annotations

import numpy as np
import pytest

from fnsi import plots
from fnsi.errors import model_errors
from fnsi.modal import ModalTable
from fnsi.nonlinear import NonlinearElement
from fnsi.stabilisation import OrderPoles, PoleClass, StabilisationDiagram, macx_matrix
from fnsi.stiffness import stiffness_curve

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
# an empty 100 dpi canvas of this size compresses to ~5 kB; drawn content adds far more
MIN_BYTES = 15_000


def _assert_png(content: bytes) -> None:
    assert content[:8] == PNG_SIGNATURE
    assert len(content) > MIN_BYTES


@pytest.fixture(autouse=True)
def no_pyplot_figures():
    """The module must not create figures in pyplot's global registry."""
    import matplotlib.pyplot as plt

    before = plt.get_fignums()
    yield
    assert plt.get_fignums() == before


def _diagram() -> StabilisationDiagram:
    rng = np.random.default_rng(0)
    poles = []
    for order in range(2, 21, 2):
        f = np.concatenate(([10.0, 30.0][: order // 2], rng.uniform(5, 50, max(order // 2 - 2, 0))))
        shapes = rng.normal(size=(f.size, 3)) + 1j * rng.normal(size=(f.size, 3))
        classes = tuple(PoleClass(list(PoleClass)[(k + order) % 5]) for k in range(f.size))
        poles.append(OrderPoles(order, ModalTable(f, np.full(f.size, 0.02), shapes,
                                                  ("a", "b", "c")), classes))
    return StabilisationDiagram(orders=tuple(range(2, 21, 2)), poles=tuple(poles),
                                band=(5.0, 50.0), auto_order=4)


def test_stabilisation_plot_with_frf_and_singular_values():
    f = np.linspace(5, 50, 400)
    frf = 1 / np.abs((10**2 - f**2) + 0.4j * f) + 1 / np.abs((30**2 - f**2) + 1.2j * f)
    _assert_png(plots.plot_stabilisation(_diagram(), frf=(f, frf),
                                         singular_values=np.logspace(0, -6, 40)))
    _assert_png(plots.plot_stabilisation(_diagram(), order=8))


def test_frf_plot():
    f = np.linspace(5, 50, 300)
    H = (1 / (20**2 - f**2 + 2j * f))[:, None, None] * np.array([[1.0], [0.5]])
    _assert_png(plots.plot_frf(f, H, 1.02 * H, output_names=("y1", "y2"), input_names=("u",)))
    with pytest.raises(ValueError, match="unknown"):
        plots.plot_frf(f, H, H, output_names=("y1", "y2"), input_names=("u",),
                       pairs=[("y9", "u")])


def test_coefficient_plot():
    f = np.linspace(5, 50, 300)
    mu = np.column_stack((100 + 0.5j * np.sin(f), 40 + 2 * np.cos(f) + 0.1j))
    _assert_png(plots.plot_coefficients(f, mu, ["clearance NC2", "clearance NC1"],
                                        truth=[100.0, None]))


def test_stiffness_plot_with_truth_and_spline_knots():
    truth = NonlinearElement("clearance", "a", "b", gap=1.5, coefficients=(100.0,))
    knots = (-3.0, -1.6, -1.4, -0.5, 0.5, 1.4, 1.6, 3.0)
    spline = NonlinearElement("spline", "a", "b", knots=knots)
    x = np.linspace(-3, 3, 500)
    ordinates = np.linalg.lstsq(spline.basis(x), truth.force(x), rcond=None)[0]
    damper = NonlinearElement("quadratic_damping", "a", coefficients=(3.0,))
    curves = [stiffness_curve(spline, ordinates), stiffness_curve(damper, x=(-1.0, 1.0))]
    _assert_png(plots.plot_stiffness(curves, truths=[truth, None]))
    _assert_png(plots.plot_stiffness(curves, warnings=["confounded (u = 0.01)", None]))
    with pytest.raises(ValueError, match="one warning"):
        plots.plot_stiffness(curves, warnings=["confounded"])


def test_stiffness_warnings_keep_the_panels_wide(monkeypatch):
    # a long warning once squeezed the panels of a 2-column grid to a sliver at each edge
    # (0.45 % of the figure width each, here); a panel should keep about half of it
    figures = []
    monkeypatch.setattr(plots, "png_bytes", figures.append)
    curves = [stiffness_curve(NonlinearElement("polynomial", f"d{k}", coefficients=(1.0,)),
                              x=(-2.0, 2.0)) for k in range(4)]
    warning = ("confounded with spline NC1w_Z-NC1b_Z, spline NC3w_Z-NC3b_Z, spline "
               "NC4w_Z-NC4b_Z, a linear spring and dashpot at the elements (u = 0.007): "
               "not to be trusted")
    plots.plot_stiffness(curves, warnings=[warning, None, warning, warning])
    figure = figures[0]
    figure.canvas.draw()
    widths = [ax.get_position().width for ax in figure.axes if ax.get_visible()]
    assert len(widths) == 4 and min(widths) > 0.35, widths


def test_macx_plot():
    rng = np.random.default_rng(1)
    shapes = rng.normal(size=(5, 8)) + 1j * rng.normal(size=(5, 8))
    values = macx_matrix(shapes, shapes + 0.1 * rng.normal(size=shapes.shape))
    f = np.array([10.7, 28.3, 30.1, 32.6, 38.3])
    _assert_png(plots.plot_macx(values, f, f))


def test_error_plot():
    rng = np.random.default_rng(2)
    t = np.arange(1000) / 1000.0
    y = np.column_stack([np.sin(2 * np.pi * 7 * t), np.cos(2 * np.pi * 13 * t)])
    measured = np.tile(y, (4, 1)) + 0.01 * rng.normal(size=(4000, 2))
    errors = model_errors(measured, 0.98 * y, 1000.0, periods=4, band=(1.0, 100.0))
    _assert_png(plots.plot_errors(errors))


def test_the_rings_at_the_chosen_order_are_the_results_confirmed_modes():
    """The stabilisation diagram and the result agree on which modes are confirmed."""
    from fnsi.identification import IdentificationSettings, identify
    from tests.fnsi.test_cli import HIDDEN
    from tests.fnsi.test_diagnosis import chain, measure

    result = identify(measure(chain(HIDDEN), 1), IdentificationSettings(
        band=(5.0, 60.0), block_rows=15, max_order=20, driving_points=(("F_x1", "x1"),)))
    points = plots.confirmed_points(result.stabilisation)
    ringed = np.sort(points[points[:, 1] == result.order, 0])
    modal = result.modal
    confirmed = np.sort(modal.frequencies[modal.confirmed])
    assert confirmed.size >= 3  # modes of the chain the automatic order keeps
    np.testing.assert_array_equal(ringed, confirmed)
