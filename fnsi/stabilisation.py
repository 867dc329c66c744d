"""Stabilisation diagram and automatic model-order choice (paper Section IV.A, Figure 5).

The poles of the identified linear state-space model are tracked over increasing model
orders, all obtained from the single singular value decomposition of the projected data
matrices (Section II.D). A pole at order n is compared with the poles at the previous
order of the diagram (the lower order is the reference, as in the paper) and receives one
of the five classes of Figure 5:

=============  ========  ============================================================
class          symbol    meaning
=============  ========  ============================================================
``new``        dot       no pole of the previous order within the frequency tolerance
``frequency``  cross     stable in natural frequency
``damping``    square    stable in frequency and damping ratio
``shape``      circle    stable in frequency and mode shape (MACX)
``stable``     triangle  stable in frequency, damping ratio and MACX (full)
=============  ========  ============================================================

Mode shapes are compared with the MACX of Vacher, Jacquier & Bucharles (2010), the MAC
extended to complex modes, because the damping of the structures of interest is strongly
non-proportional (the paper's reference 13).

A pole is *confirmed* when it stays fully stable over the next ``confirmation`` orders of
the diagram (a chain of fully stable poles, each against the previous one) and belongs
to a *column* of poles stable in frequency and shape that spans at least
``persistence + 1`` orders
(:func:`column_lengths`): a structural mode is found again at every order once the model
holds it, while poles that fit noise come and go. The automatic order
(:func:`choose_order`) is the lowest order whose linear part can be simulated (every
discrete pole inside the unit circle), that holds the most *physical* poles, and whose
estimates of them have converged to those of the highest order holding as many. A
physical pole is confirmed, inside the band less a margin at its edges
(:func:`inner_band`), and carries at least ``min_contribution`` of the fitted response in
the measured quantity, averaged over the outputs (:func:`modal_contributions`), which
rejects persistent poles that explain nothing. The identification at the automatic order
keeps the physical poles only.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from enum import StrEnum
from typing import Protocol

import numpy as np

from fnsi.modal import ModalTable, modal_table


class StateMatrixSource(Protocol):
    """Anything that returns (A, C) of a discrete-time model of a given order.

    :class:`fnsi.subspace.SubspaceDecomposition` satisfies it: every order comes from the
    same singular value decomposition, so the diagram costs one eigenproblem per order.
    """

    def state_matrices(self, order: int) -> tuple[np.ndarray, np.ndarray]:
        """State matrix A (order, order) and output matrix C (l, order)."""
        ...


class PoleClass(StrEnum):
    """Stabilisation class of a pole (paper Figure 5), from worst to best."""

    NEW = "new"
    FREQUENCY = "frequency"
    DAMPING = "damping"
    SHAPE = "shape"
    STABLE = "stable"


@dataclass(frozen=True)
class StabilisationTolerances:
    """Criteria of the stabilisation diagram.

    Attributes
    ----------
    frequency : float
        Largest relative change of natural frequency [-] (default 1 %).
    damping : float
        Largest relative change of damping ratio [-] (default 5 %).
    macx : float
        Smallest MACX between the two mode shapes [-] (default 0.98).
    max_damping : float
        Largest credible damping ratio of a structural mode [-] (default 20 %): a pole
        more damped is never stable in damping, so it is neither counted by the order
        choice nor kept. Noise and out-of-band dynamics are fitted by such poles, and
        they can persist from order to order (on the SmallSat single-nonlinearity test,
        39 outputs, an 8.9 Hz pole at 44 % damping in 2 noise realisations of 20). The
        most damped mode of our SmallSat model has 16 %; raise it for structures with
        heavier damping.
    """

    frequency: float = 0.01
    damping: float = 0.05
    macx: float = 0.98
    max_damping: float = 0.2

    def __post_init__(self) -> None:
        if not 0.0 < self.frequency < 1.0:
            raise ValueError(f"frequency tolerance must be in (0, 1); got {self.frequency}")
        if not 0.0 < self.damping < 1.0:
            raise ValueError(f"damping tolerance must be in (0, 1); got {self.damping}")
        if not 0.0 < self.macx <= 1.0:
            raise ValueError(f"MACX threshold must be in (0, 1]; got {self.macx}")
        if not 0.0 < self.max_damping <= 1.0:
            raise ValueError(f"largest damping ratio must be in (0, 1]; got {self.max_damping}")


@dataclass(frozen=True)
class OrderPoles:
    """The physical poles identified at one model order, with their classes.

    Attributes
    ----------
    order : int
        Model order n (number of states).
    modes : ModalTable
        Natural frequencies [Hz], damping ratios [-] and complex shapes (p, l) of the p
        physical poles of that order, as kept by :func:`fnsi.modal.modal_table`:
        oscillatory and stable, one per complex-conjugate pair, in or near the band; its
        ``confirmed`` flags say which poles the following orders confirm and whose column
        persists (see the module notes).
    classes : tuple of PoleClass
        Class of each pole against the previous order of the diagram.
    spectral_radius : float
        Largest |z| of all eigenvalues of the order's state matrix A [-]; at 1 or more the
        linear part is unstable and the model cannot be simulated (default 0: unknown).
    contributions : ndarray, shape (n_modes,), or None
        Share of the fitted frequency response's power over the band carried by each pole
        pair [-] (:func:`modal_contributions`); None where the order choice did not need it.
    """

    order: int
    modes: ModalTable
    classes: tuple[PoleClass, ...]
    spectral_radius: float = 0.0
    contributions: np.ndarray | None = None

    @property
    def simulable(self) -> bool:
        """Whether every discrete pole of the order lies inside the unit circle."""
        return self.spectral_radius < 1.0


def macx_matrix(shapes_a: np.ndarray, shapes_b: np.ndarray) -> np.ndarray:
    """MACX between every pair of complex mode shapes (paper Figure 6).

    MACX(a, b) = (|a^H b| + |a^T b|)^2 / ((a^H a + |a^T a|) (b^H b + |b^T b|)),
    the modal assurance criterion extended to complex modes by Vacher et al. (2010). It
    compares a shape with the subspace spanned by the other shape and its conjugate, so it
    is 1 for shapes equal up to any complex factor or conjugation, 0 for orthogonal ones
    and symmetric in its arguments.

    Parameters
    ----------
    shapes_a : ndarray, shape (na, l) or (l,), complex
        Mode shapes, one per row, at l output channels.
    shapes_b : ndarray, shape (nb, l) or (l,), complex
        Mode shapes at the same channels.

    Returns
    -------
    ndarray, shape (na, nb)
        MACX values in [0, 1].

    References
    ----------
    P. Vacher, B. Jacquier, A. Bucharles, "Extensions of the MAC criterion to complex
    modes", Proceedings of ISMA 2010, Leuven, pp. 2713-2726.

    Examples
    --------
    >>> import numpy as np
    >>> phi = np.array([1.0 + 0.2j, -0.5j, 0.3])
    >>> round(float(macx_matrix(phi, (2 - 1j) * phi.conj())[0, 0]), 12)
    1.0
    """
    a = np.atleast_2d(np.asarray(shapes_a, dtype=complex))
    b = np.atleast_2d(np.asarray(shapes_b, dtype=complex))
    if a.ndim != 2 or b.ndim != 2 or a.shape[1] != b.shape[1]:
        raise ValueError(
            f"mode shapes must be (modes, channels) arrays over the same channels; "
            f"got shapes {a.shape} and {b.shape}"
        )
    norm_a = np.sum(np.abs(a) ** 2, axis=1) + np.abs(np.sum(a * a, axis=1))
    norm_b = np.sum(np.abs(b) ** 2, axis=1) + np.abs(np.sum(b * b, axis=1))
    if np.any(norm_a == 0.0) or np.any(norm_b == 0.0):
        raise ValueError("a mode shape is identically zero; MACX is undefined for it")
    numerator = (np.abs(a.conj() @ b.T) + np.abs(a @ b.T)) ** 2
    # Rounding can push identical shapes a few ulps above 1.
    return np.minimum(numerator / np.outer(norm_a, norm_b), 1.0)


def classify_poles(
    current: ModalTable, previous: ModalTable, tolerances: StabilisationTolerances
) -> tuple[PoleClass, ...]:
    """Class of each pole of ``current`` against the poles of the lower order ``previous``.

    A pole takes the best class that any pole of the previous order within the frequency
    tolerance grants it, so a close pair of modes (e.g. 28.26 and 28.41 Hz in Table 1)
    is matched shape-by-shape rather than to the nearest frequency only. Tolerances on
    frequency and damping are relative to the previous (reference) pole.

    Parameters
    ----------
    current, previous : ModalTable
        Poles of the higher and the lower (reference) model order.
    tolerances : StabilisationTolerances
        Criteria.

    Returns
    -------
    tuple of PoleClass
        One class per pole of ``current``.
    """
    if current.n_modes == 0:
        return ()
    if previous.n_modes == 0:
        return (PoleClass.NEW,) * current.n_modes
    freq_ok, damp_ok, shape_ok = _criteria(current, previous, tolerances)
    levels = (
        (PoleClass.STABLE, freq_ok & damp_ok & shape_ok),
        (PoleClass.SHAPE, freq_ok & shape_ok),
        (PoleClass.DAMPING, freq_ok & damp_ok),
        (PoleClass.FREQUENCY, freq_ok),
    )
    classes = []
    for k in range(current.n_modes):
        classes.append(next((cls for cls, ok in levels if ok[k].any()), PoleClass.NEW))
    return tuple(classes)


def _criteria(current: ModalTable, previous: ModalTable, tolerances: StabilisationTolerances
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frequency, damping and MACX criteria of every (current, previous) pair of poles, as
    boolean matrices (n_current, n_previous); tolerances relative to the previous pole,
    and no pole above the largest credible damping is stable in damping."""
    f_ref = previous.frequencies[None, :]
    z_ref = previous.damping_ratios[None, :]
    freq_ok = np.abs(current.frequencies[:, None] - f_ref) <= tolerances.frequency * f_ref
    damp_ok = np.abs(current.damping_ratios[:, None] - z_ref) <= tolerances.damping * z_ref
    damp_ok &= current.damping_ratios[:, None] <= tolerances.max_damping
    if current.n_modes == 0 or previous.n_modes == 0:
        return freq_ok, damp_ok, freq_ok
    shape_ok = macx_matrix(current.shapes, previous.shapes) >= tolerances.macx
    return freq_ok, damp_ok, shape_ok


def confirmed_poles(modes: Sequence[ModalTable], tolerances: StabilisationTolerances,
                    confirmation: int) -> tuple[np.ndarray, ...]:
    """Which poles of each order the following orders confirm.

    A pole of order index j is confirmed when a chain of poles at orders j+1, ...,
    j+c (c = ``confirmation``, fewer near the top of the diagram) exists in which each
    pole is fully stable (frequency, damping and MACX) against the one before; the poles
    of the highest order, which nothing follows, are not confirmed.

    Parameters
    ----------
    modes : sequence of ModalTable
        Poles of increasing orders.
    tolerances : StabilisationTolerances
        Criteria of full stability.
    confirmation : int
        Number of following orders the chain must span (>= 1).

    Returns
    -------
    tuple of ndarray
        One boolean array (n_modes,) per order.

    Examples
    --------
    >>> from fnsi.modal import ModalTable
    >>> def table(f):
    ...     return ModalTable(np.array(f), np.full(len(f), 0.02), np.ones((len(f), 2)), ("a", "b"))
    >>> flags = confirmed_poles([table([10.0, 20.0]), table([10.01, 21.0]), table([10.02])],
    ...                         StabilisationTolerances(), 2)
    >>> [f.tolist() for f in flags]
    [[True, False], [True, False], [False]]
    """
    if confirmation < 1:
        raise ValueError(f"confirmation must span at least 1 order; got {confirmation}")
    links = []  # links[j][a, b]: pole a of order j + 1 is fully stable against pole b of j
    for previous, current in itertools.pairwise(modes):
        freq_ok, damp_ok, shape_ok = _criteria(current, previous, tolerances)
        links.append(freq_ok & damp_ok & shape_ok)
    flags = []
    for j, table in enumerate(modes):
        reach = np.eye(table.n_modes, dtype=bool)  # reach[a, b]: chain from pole b to a
        for link in links[j:j + confirmation]:
            reach = (link.astype(int) @ reach.astype(int)) > 0
        flags.append(reach.any(axis=0) if j < len(links) else np.zeros(table.n_modes, bool))
    return tuple(flags)


def column_lengths(modes: Sequence[ModalTable], tolerances: StabilisationTolerances
                   ) -> tuple[np.ndarray, ...]:
    """Number of orders spanned by the longest column of poles through each pole.

    A column is a chain of poles at successive orders of the diagram, each stable in
    frequency and mode shape (MACX) against the one before, with a credible damping
    (at most ``tolerances.max_damping``). A structural mode, once the model holds it, is
    found again at every higher order, so its column spans most of the diagram; a pole
    that fits noise or out-of-band dynamics moves as the order changes and its column is
    short (on 24 random 5-DOF chains with 0.5 % noise, diagram up to order 50: median 27
    orders for poles matching a true mode, 1 for the others). The damping ratio, the
    noisiest of the three, is left out of the links: a lightly damped mode whose estimate
    scatters by a few percent from order to order (0.93, 0.98, 0.90 % at orders 4, 6, 8
    of a 2-DOF test with 1 % noise) is still the same mode, and the confirmation at the
    next order already asks for full stability.

    Parameters
    ----------
    modes : sequence of ModalTable
        Poles of increasing orders.
    tolerances : StabilisationTolerances
        Criteria of full stability.

    Returns
    -------
    tuple of ndarray of int
        One array (n_modes,) per order: the orders spanned, the pole's own included (1 for
        a pole stable against nothing).

    Examples
    --------
    >>> from fnsi.modal import ModalTable
    >>> def table(f):
    ...     return ModalTable(np.array(f), np.full(len(f), 0.02), np.ones((len(f), 2)), ("a", "b"))
    >>> spans = column_lengths([table([10.0, 20.0]), table([10.01, 21.0]), table([10.02])],
    ...                        StabilisationTolerances())
    >>> [s.tolist() for s in spans]
    [[3, 1], [3, 1], [3]]
    """
    links = []
    for previous, current in itertools.pairwise(modes):
        freq_ok, _, shape_ok = _criteria(current, previous, tolerances)
        credible = current.damping_ratios[:, None] <= tolerances.max_damping
        links.append(freq_ok & shape_ok & credible)
    before = [np.zeros(modes[0].n_modes, dtype=int)]  # stable links below each pole
    for link in links:
        reached = np.where(link, before[-1][None, :] + 1, 0)
        before.append(reached.max(axis=1, initial=0))
    after = [np.zeros(modes[-1].n_modes, dtype=int)]  # stable links above each pole
    for link in reversed(links):
        reached = np.where(link, after[0][:, None] + 1, 0)
        after.insert(0, reached.max(axis=0, initial=0))
    return tuple(b + a + 1 for b, a in zip(before, after, strict=True))


def modal_contributions(A: np.ndarray, B: np.ndarray, C: np.ndarray, fs: float,
                        frequencies: np.ndarray, modes: ModalTable,
                        inputs: np.ndarray | None = None) -> np.ndarray:
    """Share of the fitted response's power carried by each mode, averaged over outputs.

    With A = V diag(lambda) V^-1, the response C (zI - A)^-1 B U is the sum of the pole
    terms R_r U / (z - lambda_r), R_r = (C V)_r (V^-1 B)_r. The power of a mode at output
    c is that of its pole pair's terms, summed over the lines (and realisations), and its
    share there is that power over the power of the whole response at c; the returned
    share is the mean over the outputs, so that every channel weighs alike, whatever its
    unit or level (a mode that dominates a quiet sensor matters as much as one that
    dominates a loud one; summed over channels, a mode at 13.6 % of the response of a
    3-DOF chain's sensors, mostly at the weaker one, weighed 0.09 %). The shares need
    not add to 1 when modes overlap. A pole that fits nothing the inputs drive has a share
    near zero, however persistent it is in the diagram.

    Parameters
    ----------
    A : ndarray, shape (n, n)
        Discrete-time state matrix (sample time 1 / fs).
    B : ndarray, shape (n, m)
        Input matrix of the measured inputs (the basis-function columns left out: the
        share is of the underlying linear response).
    C : ndarray, shape (l, n)
    fs : float
        Sampling rate [Hz].
    frequencies : ndarray, shape (N,)
        Lines [Hz] over which the power is summed (the analysis band).
    modes : ModalTable
        The modes of (A, C) to evaluate (:func:`fnsi.modal.modal_table`); each is matched
        to the eigenvalue of A nearest to its pole.
    inputs : ndarray, shape (R, N, m), complex, optional
        Input spectra U on those lines (R realisations), which weigh the lines and inputs
        as the measurement does, times (j omega)^p where the measured quantity is the p-th
        derivative of the model's output; None: unit inputs (the frequency response).

    Returns
    -------
    ndarray, shape (n_modes,)
        Shares in [0, ~1] [-].

    Examples
    --------
    >>> lam = np.exp((-0.02 * 20 * np.pi + 20j * np.pi) / 1000.0)  # 10 Hz, 2 %
    >>> A = np.array([[lam.real, lam.imag], [-lam.imag, lam.real]])
    >>> B, C = np.array([[0.0], [1.0]]), np.array([[1.0, 0.0]])
    >>> from fnsi.modal import modal_table
    >>> modes = modal_table(A, C, 1000.0, ("y",))
    >>> round(float(modal_contributions(A, B, C, 1000.0, np.linspace(5, 15, 50), modes)[0]), 6)
    1.0
    """
    lam, V = np.linalg.eig(A)
    frequencies = np.asarray(frequencies, dtype=float)
    U = (np.ones((1, frequencies.size, B.shape[1])) if inputs is None
         else np.asarray(inputs).reshape(-1, frequencies.size, B.shape[1]))
    z = np.exp(2j * np.pi * frequencies / fs)
    # (R, N, l, n): the response of each pole at each output, inputs summed
    drive = np.einsum("nm,rkm->rkn", np.linalg.solve(V, B), U)
    terms = (C @ V)[None, None] * (drive / (z[None, :, None] - lam[None, None, :]))[:, :, None]
    total = np.sum(np.abs(terms.sum(axis=3)) ** 2, axis=(0, 1))  # (l,)
    total = np.where(total > 0, total, np.inf)
    poles = (-modes.damping_ratios + 1j * np.sqrt(1 - modes.damping_ratios ** 2)) \
        * 2 * np.pi * modes.frequencies
    z_modes = np.exp(poles / fs)[:, None]
    upper = np.argmin(np.abs(lam[None, :] - z_modes), axis=1)         # (n_modes,)
    lower = np.argmin(np.abs(lam[None, :] - z_modes.conj()), axis=1)
    power = np.sum(np.abs(terms[..., upper] + terms[..., lower]) ** 2, axis=(0, 1))  # (l, modes)
    return np.mean(power / total[:, None], axis=0)


#: Fraction of the tracking tolerances (:class:`StabilisationTolerances` frequency and
#: damping) within which a lower order's physical poles must agree with the highest order
#: holding as many, to count as converged (:func:`choose_order`). The tracking tolerances
#: say that two poles are one mode; converged estimates must agree more closely than that.
CONVERGENCE = 0.5


def choose_order(poles: Sequence[OrderPoles], band: tuple[float, float],
                 contributions: Callable[[int], np.ndarray] | None = None,
                 min_contribution: float = 1e-2,
                 tolerances: StabilisationTolerances | None = None) -> int | None:
    """Automatic model order: the lowest simulable order holding the most physical poles
    whose estimates have converged.

    A pole of an order is physical when it is confirmed (``modes.confirmed``: fully stable
    at the next order and on a persistent column, see :func:`stabilisation_diagram`), its
    natural frequency lies inside ``band`` and, when ``contributions`` is given, it carries
    at least ``min_contribution`` of the fitted response's power over the band; with
    ``tolerances``, two poles that are one mode split by the model count once
    (:func:`distinct_poles`, which tells them from two close modes by their shapes or by
    the persistence of both columns at the neighbouring orders). A structural mode the
    data hold appears at some order and stays, so the count reaches the number of such
    modes and stays there, while each added order only adds poles that fit noise, which
    are neither persistent nor contributing.

    The rule, in three steps:

    1. the most physical poles any order holds; orders whose linear part can be simulated
       (:attr:`OrderPoles.simulable`) are preferred among those holding that many. When
       no simulable order does, the unstable ones are taken (their unstable poles are never
       physical, since :func:`fnsi.modal.modal_table` drops them, and the identification
       reflects them inside the unit circle, :func:`reflect_unstable_poles`);
    2. of these orders, the highest is the reference: its surplus states absorb the noise
       and the dynamics outside the band, which at lower orders pull the physical poles
       (heavily damped modes move by 1-2 % in frequency between orders 12 and 26 on the
       generalisation benchmark's grids, :func:`converged`);
    3. the lowest of these orders whose physical poles agree with the reference's within
       :data:`CONVERGENCE` of the tracking tolerances: the fewest states that give the
       converged estimates (a state that only fits noise costs accuracy in the nonlinear
       coefficients: on the SmallSat single record the clearance coefficient is 1.4 % off
       at order 44 and 0.2 % at order 6).

    Contributions cost a least-squares fit of B per order, so they are evaluated lazily:
    the count without them bounds the count with them, and orders are visited from the
    largest bound down (each order at most once).

    Parameters
    ----------
    poles : sequence of OrderPoles
        The diagram's poles, increasing orders, with confirmed flags.
    band : (float, float)
        Analysis band [Hz].
    contributions : callable(order) -> ndarray, optional
        Share of each pole of that order (:func:`modal_contributions`); None counts
        confirmed poles only.
    tolerances : StabilisationTolerances, optional
        Frequency and MACX tolerances under which two poles of one order are one mode, and
        the tracking tolerances the convergence is judged against (default
        :class:`StabilisationTolerances`).
    min_contribution : float
        Smallest share of a physical pole [-] (default 1 %: the share of the measured
        response, averaged over the outputs, below which a mode is not taken to matter;
        the poles that fit noise carry 1e-7 to 1e-5 on the chains of
        :func:`column_lengths`). Weaker modes are found by asking for an explicit order:
        counting them drives the choice to orders where the model also fits noise (on
        the SmallSat single record a 32.6 Hz mode with 0.5 % of the response is held only
        from order 44 up).

    Returns
    -------
    int or None
        The chosen order, or None when no order holds a confirmed pole in the band (the
        user must then choose an order from the diagram).

    Examples
    --------
    >>> from fnsi.modal import ModalTable
    >>> def order(n, f, confirmed, radius=0.99):
    ...     t = ModalTable(np.array(f), np.full(len(f), 0.02), np.ones((len(f), 1)), ("y",),
    ...                    np.array(confirmed))
    ...     return OrderPoles(n, t, (PoleClass.STABLE,) * len(f), radius)
    >>> diagram = [order(2, [10.0], [True]), order(4, [10.0, 20.0], [True, True], 1.001),
    ...            order(6, [10.0, 20.0, 33.0], [True, True, False]),
    ...            order(8, [10.0, 20.0, 33.0], [True, True, False])]
    >>> choose_order(diagram, (5.0, 50.0))
    6
    """
    kept: dict[int, np.ndarray] = {}
    index = {p.order: k for k, p in enumerate(poles)}

    def bound(p: OrderPoles) -> int:
        return int(np.sum(physical_mask(p, band)))

    def physical(p: OrderPoles) -> np.ndarray:
        if p.order not in kept:
            keep = physical_mask(p, band)
            shares = None if contributions is None else contributions(p.order)
            if shares is not None:
                keep &= shares >= min_contribution
            if tolerances is not None:
                keep = distinct_poles(p.modes, keep, shares, tolerances,
                                      neighbour_frequencies(poles, index[p.order]))
            kept[p.order] = keep
        return kept[p.order]

    def count(p: OrderPoles) -> int:
        return int(np.sum(physical(p)))

    def best(pool: list[OrderPoles]) -> tuple[int, int] | None:
        """(count, order) of the lowest order with the most physical poles (at least 1)."""
        found: tuple[int, int] | None = None
        ranked = sorted((p for p in pool if bound(p) >= 1), key=lambda p: (-bound(p), p.order))
        for p in ranked:
            if found is not None and (bound(p), -p.order) <= (found[0], -found[1]):
                break
            better = found is None or (count(p), -p.order) > (found[0], -found[1])
            if count(p) >= 1 and better:
                found = (count(p), p.order)
        return found

    overall = best(list(poles))
    if overall is None:
        return None

    def holding(pool: Sequence[OrderPoles]) -> list[OrderPoles]:
        return [p for p in pool if bound(p) >= overall[0] and count(p) >= overall[0]]

    candidates = holding([p for p in poles if p.simulable]) or holding(poles)
    reference = candidates[-1]
    tracking = StabilisationTolerances() if tolerances is None else tolerances
    return next(p.order for p in candidates
                if converged(p.modes.subset(physical(p)),
                             reference.modes.subset(physical(reference)), tracking))


def converged(modes: ModalTable, reference: ModalTable,
              tolerances: StabilisationTolerances) -> bool:
    """Whether every mode of ``modes`` lies within :data:`CONVERGENCE` of the tracking
    tolerances of the ``reference`` mode nearest in frequency (relative to it): frequency
    within 0.5 % and damping ratio within 2.5 % with the default tolerances.

    Examples
    --------
    >>> from fnsi.modal import ModalTable
    >>> def table(f, z):
    ...     return ModalTable(np.array(f), np.array(z), np.ones((len(f), 1)), ("y",))
    >>> reference = table([10.0, 20.0], [0.05, 0.02])
    >>> converged(table([10.02, 20.0], [0.0505, 0.02]), reference, StabilisationTolerances())
    True
    >>> converged(table([10.2, 20.0], [0.05, 0.02]), reference, StabilisationTolerances())
    False
    """
    if reference.n_modes == 0:
        return modes.n_modes == 0
    nearest = np.argmin(np.abs(modes.frequencies[:, None] - reference.frequencies[None, :]),
                        axis=1)
    f_ref, z_ref = reference.frequencies[nearest], reference.damping_ratios[nearest]
    return bool(np.all(np.abs(modes.frequencies - f_ref)
                       <= CONVERGENCE * tolerances.frequency * f_ref)
                and np.all(np.abs(modes.damping_ratios - z_ref)
                           <= CONVERGENCE * tolerances.damping * z_ref))


def reflect_unstable_poles(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """State matrix with every eigenvalue outside the unit circle reflected inside it.

    An eigenvalue z with |z| >= 1 becomes 1 / conj(z): same angle, so the same damped
    frequency, and the negative damping of the unstable pole turns into the same positive
    damping. The eigenvectors are kept, so the mode shapes at the outputs are unchanged;
    the response of the reflected pole keeps its magnitude on the unit circle and changes
    its phase, so B and D must be fitted again. Conjugate pairs stay pairs and A stays
    real. A pole exactly on the unit circle (|z| = 1, no damping) is moved to
    |z| = 1 - 1e-9.

    Parameters
    ----------
    A : ndarray, shape (n, n)
        Discrete-time state matrix.

    Returns
    -------
    A : ndarray, shape (n, n)
        The stabilised state matrix (``A`` itself when nothing is unstable).
    reflected : ndarray, shape (k,), complex
        The eigenvalues that were reflected (before reflection).

    Examples
    --------
    >>> A = np.array([[1.001, 0.0], [0.0, 0.5]])
    >>> B, z = reflect_unstable_poles(A)
    >>> np.round(np.diag(B), 6).tolist(), z.real.tolist()
    ([0.999001, 0.5], [1.001])
    """
    lam, V = np.linalg.eig(A)
    outside = np.abs(lam) >= 1.0
    if not outside.any():
        return A, lam[outside]
    inside = lam.copy()
    inside[outside] = 1.0 / np.conj(lam[outside])
    inside[outside & (np.abs(inside) >= 1.0)] *= 1.0 - 1e-9
    return np.real(V @ np.diag(inside) @ np.linalg.inv(V)), lam[outside]


#: Share of the band's width at each edge where a pole is not taken for a mode.
EDGE_MARGIN = 0.02


def inner_band(band: tuple[float, float]) -> tuple[float, float]:
    """The band less :data:`EDGE_MARGIN` of its width at each edge [Hz].

    The model has no other way to bend its response near an edge toward the modes just
    outside the band than poles at the edge itself, and these are persistent: on the
    SmallSat single record (band 5-50 Hz, a mode at 50.4 Hz) orders 26-54 hold a
    confirmed pole at 49.85-49.99 Hz with damping below 0.03 %, carrying 0.4-13 % of the
    fitted response. Such a pole's frequency is set by the edge as much as by the
    structure, so a mode is reported only inside this inner band; widen the band to
    identify a mode near an edge. The margin is small against the band (0.9 Hz of 45 Hz)
    and costs no mode on the generalisation benchmark, whose required modes all lie
    inside 2 % of their band's edges.

    Examples
    --------
    >>> inner_band((5.0, 55.0))
    (6.0, 54.0)
    """
    margin = EDGE_MARGIN * (band[1] - band[0])
    return band[0] + margin, band[1] - margin


def physical_mask(poles: OrderPoles, band: tuple[float, float],
                  min_contribution: float | None = None,
                  tolerances: StabilisationTolerances | None = None,
                  neighbours: Sequence[np.ndarray] = ()) -> np.ndarray:
    """Which poles of an order are physical (see :func:`choose_order`), shape (n_modes,).

    The contribution test applies when ``min_contribution`` is given and the order's
    ``contributions`` were evaluated; with ``tolerances``, of two physical poles that are
    one mode (:func:`distinct_poles`, with the ``neighbours``' confirmed frequencies
    [Hz]) only the one carrying more response is kept.
    """
    modes = poles.modes
    keep = np.zeros(modes.n_modes, bool) if modes.confirmed is None else modes.confirmed.copy()
    low, high = inner_band(band)
    keep &= (modes.frequencies >= low) & (modes.frequencies <= high)
    if min_contribution is not None and poles.contributions is not None:
        keep &= poles.contributions >= min_contribution
    if tolerances is not None:
        keep = distinct_poles(modes, keep, poles.contributions, tolerances, neighbours)
    return keep


def distinct_poles(modes: ModalTable, keep: np.ndarray, weights: np.ndarray | None,
                   tolerances: StabilisationTolerances,
                   neighbours: Sequence[np.ndarray] = ()) -> np.ndarray:
    """``keep`` without the poles that repeat a kept one, shape (n_modes,).

    Two poles of one order are one mode when their frequencies differ by at most the
    frequency tolerance, their shapes match (MACX at least the threshold) and the
    ``neighbours`` do not hold them as two columns (:func:`two_columns`): a model of
    higher order can split a structural mode into two such poles, which would otherwise
    count twice in the order choice and be reported twice. Poles are taken by decreasing
    ``weights`` (their contributions; None: in order), and a pole is dropped when it
    repeats one already taken. Close modes with different shapes stay apart, and so do
    close modes whose shapes the outputs cannot tell apart (with one output the MACX is
    always 1) when both persist at the neighbouring orders.

    Parameters
    ----------
    modes : ModalTable
        The poles of one order.
    keep : ndarray of bool, shape (n_modes,)
        The candidates.
    weights : ndarray, shape (n_modes,), optional
        Their shares of the response (:func:`modal_contributions`).
    tolerances : StabilisationTolerances
        Frequency and MACX thresholds.
    neighbours : sequence of ndarray
        Confirmed natural frequencies [Hz] of the orders just below and just above
        (:func:`neighbour_frequencies`); empty: no persistence evidence, so poles of one
        shape within the frequency tolerance are always one mode.
    """
    order = np.flatnonzero(keep)
    if weights is not None:
        order = order[np.argsort(-weights[order], kind="stable")]
    frequencies = modes.frequencies
    taken: list[int] = []
    for k in order:
        f = frequencies[k]
        near = [t for t in taken
                if abs(frequencies[t] - f) <= tolerances.frequency * frequencies[t]]
        repeats = [t for t in near
                   if macx_matrix(modes.shapes[k], modes.shapes[t])[0, 0] >= tolerances.macx
                   and not two_columns(f, frequencies[t], neighbours)]
        if not repeats:
            taken.append(int(k))
    out = np.zeros_like(keep)
    out[taken] = True
    return out


def two_columns(f_a: float, f_b: float, neighbours: Sequence[np.ndarray]) -> bool:
    """Whether poles at ``f_a`` and ``f_b`` [Hz] of one order persist as two columns at
    both neighbouring orders.

    A model that splits one structural mode does so at isolated orders, and the two poles
    stand for one: at the orders around, a single pole holds the place (on the
    generalisation benchmark, a 38.3 Hz mode split into 38.37 and 38.61 Hz at order 30
    only). Two close modes are held by two poles at every order from the one that first
    resolves them (a 145.8 / 146.4 Hz pair seen with one output, orders 10 to 58). Each
    neighbour must hold two distinct confirmed poles, the one nearest ``f_a`` closer to it
    than to ``f_b`` and the one nearest ``f_b`` closer to it than to ``f_a``: the columns
    do not cross or merge.

    Parameters
    ----------
    f_a, f_b : float
        Natural frequencies of the two poles [Hz].
    neighbours : sequence of ndarray
        Confirmed natural frequencies [Hz] of the orders just below and just above; fewer
        than two (the diagram's first or last order): no evidence, False.

    Examples
    --------
    >>> two_columns(20.0, 20.1, [np.array([20.01, 20.09]), np.array([19.99, 20.11, 30.0])])
    True
    >>> two_columns(20.0, 20.1, [np.array([20.01, 20.09]), np.array([20.04, 30.0])])
    False
    """
    if len(neighbours) < 2:
        return False
    for found in neighbours:
        if found.size < 2:
            return False
        a = found[np.argmin(np.abs(found - f_a))]
        b = found[np.argmin(np.abs(found - f_b))]
        if a == b or abs(a - f_a) >= abs(a - f_b) or abs(b - f_b) >= abs(b - f_a):
            return False
    return True


def neighbour_frequencies(poles: Sequence[OrderPoles], index: int) -> tuple[np.ndarray, ...]:
    """Confirmed natural frequencies [Hz] of the orders just below and just above
    ``poles[index]`` (:func:`two_columns`); empty at the diagram's first and last order."""
    if index == 0 or index == len(poles) - 1:
        return ()
    return tuple(p.modes.frequencies[p.modes.confirmed] if p.modes.confirmed is not None
                 else np.zeros(0) for p in (poles[index - 1], poles[index + 1]))


def _stable_counts(poles: Sequence[OrderPoles], band: tuple[float, float]) -> np.ndarray:
    """Number of fully stable poles with a natural frequency inside ``band``, per order."""
    low, high = band
    return np.array([
        sum(
            cls is PoleClass.STABLE and low <= f <= high
            for cls, f in zip(p.classes, p.modes.frequencies, strict=True)
        )
        for p in poles
    ], dtype=int)


def _confirmed_counts(poles: Sequence[OrderPoles], band: tuple[float, float]) -> np.ndarray:
    """Number of confirmed poles with a natural frequency inside ``band``, per order (0
    where the poles carry no flags)."""
    low, high = band
    return np.array([
        0 if p.modes.confirmed is None
        else int(np.sum(p.modes.confirmed & (p.modes.frequencies >= low)
                        & (p.modes.frequencies <= high)))
        for p in poles
    ], dtype=int)


@dataclass(frozen=True)
class StabilisationDiagram:
    """Poles over model orders with their stabilisation classes (paper Figure 5).

    Attributes
    ----------
    orders : tuple of int
        Model orders, increasing.
    poles : tuple of OrderPoles
        Poles and classes at each order.
    band : tuple of float
        Analysis band (low, high) [Hz]; only poles inside count for the order choice.
    tolerances : StabilisationTolerances
        Criteria used for the classes.
    persistence : int
        Steps (stable in frequency and shape) a pole's column must span, at least
        ``persistence + 1`` orders (:func:`column_lengths`), for the pole to be confirmed.
    auto_order : int or None
        Order chosen by :func:`choose_order` (None if nothing stabilises). A user
        overrides it simply by asking the identification for another order.
    confirmation : int
        Following orders over which a pole must stay fully stable to be confirmed
        (:func:`confirmed_poles`; the flags are in each order's ``modes.confirmed``).
    min_contribution : float
        Smallest share of the fitted response a physical pole carries (:func:`choose_order`).
    """

    orders: tuple[int, ...]
    poles: tuple[OrderPoles, ...]
    band: tuple[float, float]
    tolerances: StabilisationTolerances = field(default_factory=StabilisationTolerances)
    persistence: int = 3
    auto_order: int | None = None
    confirmation: int = 1
    min_contribution: float = 1e-2

    def at(self, order: int) -> OrderPoles:
        """Poles of one order of the diagram (ValueError listing the orders if absent)."""
        if order not in self.orders:
            raise ValueError(
                f"order {order} is not in the diagram; choose one of {list(self.orders)}"
            )
        return self.poles[self.orders.index(order)]

    def stable_counts(self) -> np.ndarray:
        """Number of fully stable poles inside the band at each order, shape (orders,)."""
        return _stable_counts(self.poles, self.band)

    def confirmed_counts(self) -> np.ndarray:
        """Number of confirmed poles inside the band at each order, shape (orders,)."""
        return _confirmed_counts(self.poles, self.band)

    def physical(self, order: int) -> np.ndarray:
        """Which poles of an order are physical (:func:`choose_order`), shape (n_modes,):
        the modes the automatic order keeps."""
        return physical_mask(self.at(order), self.band, self.min_contribution, self.tolerances,
                             neighbour_frequencies(self.poles, self.orders.index(order)))

    def simulable_orders(self) -> tuple[int, ...]:
        """Orders whose linear part is stable (every discrete pole inside the unit circle)."""
        return tuple(p.order for p in self.poles if p.simulable)

    def to_json(self, *, shapes: bool = False) -> dict:
        """JSON-ready description; mode shapes (as [re, im] pairs) only when asked."""
        def pole_json(p: OrderPoles, k: int) -> dict:
            entry = {
                "frequency_hz": float(p.modes.frequencies[k]),
                "damping_ratio": float(p.modes.damping_ratios[k]),
                "class": str(p.classes[k]),
                "confirmed": None if p.modes.confirmed is None else bool(p.modes.confirmed[k]),
                "contribution": (None if p.contributions is None
                                 else float(p.contributions[k])),
            }
            if shapes:
                entry["shape"] = np.column_stack(
                    (p.modes.shapes[k].real, p.modes.shapes[k].imag)).tolist()
            return entry

        return {
            "orders": list(self.orders),
            "band_hz": list(self.band),
            "tolerances": {
                "frequency": self.tolerances.frequency,
                "damping": self.tolerances.damping,
                "macx": self.tolerances.macx,
                "max_damping": self.tolerances.max_damping,
            },
            "persistence": self.persistence,
            "confirmation": self.confirmation,
            "auto_order": self.auto_order,
            "min_contribution": self.min_contribution,
            "spectral_radii": [p.spectral_radius for p in self.poles],
            "stable_counts": self.stable_counts().tolist(),
            "confirmed_counts": self.confirmed_counts().tolist(),
            "poles": [
                {"order": p.order, "poles": [pole_json(p, k) for k in range(p.modes.n_modes)]}
                for p in self.poles
            ],
        }


def stabilisation_diagram(
    decomposition: StateMatrixSource,
    fs: float,
    *,
    max_order: int = 60,
    orders: Sequence[int] | None = None,
    band: tuple[float, float] | None = None,
    output_names: Sequence[str] | None = None,
    tolerances: StabilisationTolerances | None = None,
    persistence: int = 3,
    confirmation: int = 1,
    contributions: Callable[[int, ModalTable], np.ndarray] | None = None,
    min_contribution: float = 1e-2,
    choose: bool = True,
) -> StabilisationDiagram:
    """Build the stabilisation diagram from one subspace decomposition.

    Parameters
    ----------
    decomposition : StateMatrixSource
        Typically :class:`fnsi.subspace.SubspaceDecomposition` computed at ``max_order``.
    fs : float
        Sampling rate [Hz]; the state matrices are discrete-time with dt = 1 / fs.
    max_order : int
        Largest order; the default orders are the even ones 2, 4, ..., ``max_order``
        (each vibration mode is a pair of complex-conjugate poles).
    orders : sequence of int, optional
        Explicit increasing orders instead of the default ones.
    band : (float, float), optional
        Analysis band [Hz]; default (0, fs / 2). Poles far outside it are dropped (see
        :func:`fnsi.modal.modal_table`) and only poles inside count for the order rule.
    output_names : sequence of str, optional
        Names of the output channels (the columns of the mode shapes).
    tolerances : StabilisationTolerances, optional
        Criteria; default 1 % frequency, 5 % damping, MACX 0.98.
    persistence : int
        Steps, stable in frequency and shape, the column of a confirmed pole spans
        (:func:`column_lengths`): a confirmed pole is found over at least
        ``persistence + 1`` successive orders.
        Default 3: three order increments. On the chains of :func:`column_lengths`
        (with fully stable links) 2 to 6 chose alike and 8 lost one chain's modes, which
        appear late in the diagram.
    confirmation : int
        Following orders over which a pole must stay fully stable to be confirmed, see
        :func:`confirmed_poles`. Default 1, the paper's test between two successive
        orders. More orders reject more poorly identified poles (on the SmallSat data, 39
        outputs, noise seed 0, 2 rejects the 32.7 Hz pole of order 10, 0.24 % off in
        frequency, which order 12 matches and 14 loses) but also accurate, lightly damped
        modes whose damping estimate scatters by more than the 5 % tolerance from order to
        order (a 27.6 Hz mode at 0.5 % damping of a two-DOF test with 1 % noise: 0.54,
        0.54, 0.51 % at orders 4, 6, 8).
    contributions : callable(order, modes) -> ndarray, optional
        Share of each pole of ``modes`` (the order's modal table) in the fitted response
        over the band (:func:`modal_contributions`), for the order choice; called only
        for the orders the choice needs. None: poles are judged by the diagram alone.
    min_contribution : float
        Smallest share of a physical pole, see :func:`choose_order`.
    choose : bool
        Choose the automatic order (False: ``auto_order`` None, no contribution
        evaluated; :func:`order_chosen` chooses it later).

    Returns
    -------
    StabilisationDiagram

    Examples
    --------
    >>> import numpy as np
    >>> from scipy.signal import cont2discrete
    >>> class Exact:  # one mode at 10 Hz, 2 % damping, seen by two sensors
    ...     def state_matrices(self, order):
    ...         w = 2 * np.pi * 10.0
    ...         Ac = np.array([[0.0, 1.0], [-w * w, -2 * 0.02 * w]])
    ...         A = cont2discrete((Ac, np.eye(2), np.eye(2), 0 * np.eye(2)), 1e-3)[0]
    ...         return A, np.array([[1.0, 0.0], [0.5, 0.0]])
    >>> d = stabilisation_diagram(Exact(), 1000.0, max_order=8)
    >>> d.auto_order, [str(c) for c in d.at(4).classes]
    (2, ['stable'])
    """
    if fs <= 0:
        raise ValueError(f"sampling rate fs must be positive; got {fs} Hz")
    chosen = tuple(range(2, max_order + 1, 2)) if orders is None else tuple(orders)
    if len(chosen) < 2 or np.any(np.diff(chosen) <= 0):
        raise ValueError(
            f"the diagram needs at least two increasing orders; got {list(chosen)} "
            f"(raise max_order or pass more orders)"
        )
    if chosen[0] < 1:
        raise ValueError(f"model orders must be positive; got {chosen[0]}")
    band = (0.0, fs / 2.0) if band is None else (float(band[0]), float(band[1]))
    if not 0.0 <= band[0] < band[1]:
        raise ValueError(f"band must be (low, high) with 0 <= low < high Hz; got {band}")
    tolerances = StabilisationTolerances() if tolerances is None else tolerances

    tables: list[ModalTable] = []
    radii: list[float] = []
    for order in chosen:
        A, C = decomposition.state_matrices(order)
        names = tuple(output_names) if output_names is not None else tuple(
            f"y{k}" for k in range(C.shape[0]))
        tables.append(modal_table(A, C, fs, names, band=band))
        radii.append(float(np.max(np.abs(np.linalg.eigvals(A)))))
    if persistence < 1:
        raise ValueError(f"persistence must be at least 1 order; got {persistence}")
    flags = confirmed_poles(tables, tolerances, confirmation)
    spans = column_lengths(tables, tolerances)
    poles = tuple(
        OrderPoles(order=order, modes=replace(modes, confirmed=confirmed & (span > persistence)),
                   classes=((PoleClass.NEW,) * modes.n_modes if j == 0
                            else classify_poles(modes, tables[j - 1], tolerances)),
                   spectral_radius=radius)
        for j, (order, modes, confirmed, span, radius) in enumerate(
            zip(chosen, tables, flags, spans, radii, strict=True)))
    diagram = StabilisationDiagram(
        orders=chosen, poles=poles, band=band, tolerances=tolerances,
        persistence=persistence, confirmation=confirmation, min_contribution=min_contribution)
    return order_chosen(diagram, contributions) if choose else diagram


def order_chosen(diagram: StabilisationDiagram,
                 contributions: Callable[[int, ModalTable], np.ndarray] | None = None
                 ) -> StabilisationDiagram:
    """The diagram with its automatic order (:func:`choose_order`) and the contributions
    of the orders the choice evaluated (``contributions`` as in
    :func:`stabilisation_diagram`)."""
    shares: dict[int, np.ndarray] = {}

    def share(order: int) -> np.ndarray:
        shares[order] = contributions(order, diagram.at(order).modes)
        return shares[order]

    auto_order = choose_order(diagram.poles, diagram.band,
                              None if contributions is None else share,
                              diagram.min_contribution, diagram.tolerances)
    return replace(diagram, auto_order=auto_order,
                   poles=tuple(replace(p, contributions=shares.get(p.order))
                               for p in diagram.poles))
