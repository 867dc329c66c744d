"""Random lumped mass-spring-damper structures and their exact continuous-time modes.

Written with numpy and scipy only, independently of ``fnsi``: the benchmark must not
inherit the library's assumptions (its simulator, its state-space conventions).

A structure is n point masses on one axis, linear springs between two masses or from a
mass to ground, and viscous damping, either proportional (classical normal modes, each
mode's damping ratio drawn) or not (discrete dashpots mixed in: complex modes).
Matrices are SI: M [kg], C [N s/m], K [N/m], all (n, n). Optional nonlinear
:class:`Element` s (the hidden effects of issue 21) add restoring forces; a structure with
elements is simulated by :mod:`.integration`, one without exactly by :mod:`.synthesis`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

TOPOLOGIES = ("chain", "tree", "grid")
DAMPING_KINDS = ("proportional", "nonproportional")
#: Range of every mode's damping ratio [-] (issue 20: 0.5-10 %).
DAMPING_RANGE = (0.005, 0.10)
GROUND = -1
ELEMENT_KINDS = ("cubic", "quadratic", "clearance", "coulomb", "quadratic_damping")


@dataclass(frozen=True)
class Element:
    """A nonlinear restoring force between DOF ``dof`` and ``ref`` (or ground).

    With x and v the displacement and velocity of ``dof`` relative to ``ref``, the force
    on ``dof`` (its opposite on ``ref``) is -g(x, v), with g by ``kind``:

    ===================  ==============================================================
    cubic                k x^3 (k > 0 hardening, k < 0 softening)
    quadratic            k x^2
    clearance            k (x - g+) above g+, k (x + g-) below -g-, 0 between; an
                         infinite gap leaves that side open (a one-sided stop)
    coulomb              F tanh(v / width), friction smoothed over ``width`` [m/s]
    quadratic_damping    c v |v|
    ===================  ==============================================================

    Attributes
    ----------
    kind : str
        One of :data:`ELEMENT_KINDS`.
    dof, ref : int
        DOFs; ``ref`` is :data:`GROUND` for an element to ground.
    coefficient : float
        k [N/m^3, N/m^2, N/m], F [N] or c [N s^2/m^2].
    gaps : (float, float)
        (g-, g+) [m] of a clearance, each >= 0 or infinite.
    width : float
        Smoothing velocity of Coulomb friction [m/s].
    """

    kind: str
    dof: int
    ref: int
    coefficient: float
    gaps: tuple[float, float] = (np.inf, np.inf)
    width: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in ELEMENT_KINDS:
            raise ValueError(f"element kind must be one of {ELEMENT_KINDS}; got {self.kind!r}")
        if self.kind == "coulomb" and not self.width > 0:
            raise ValueError(f"Coulomb friction needs a smoothing width > 0; got {self.width}")

    def g(self, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Restoring force g(x, v) [N] of the relative motion, same shape as ``x``."""
        k = self.coefficient
        if self.kind == "cubic":
            return k * x**3
        if self.kind == "quadratic":
            return k * x**2
        if self.kind == "coulomb":
            return k * np.tanh(v / self.width)
        if self.kind == "quadratic_damping":
            return k * v * np.abs(v)
        low, high = self.gaps
        return k * (np.maximum(x - high, 0.0) + np.minimum(x + low, 0.0))


@dataclass(frozen=True)
class Structure:
    """A lumped structure: its linear part and optional nonlinear elements.

    Attributes
    ----------
    topology : str
        One of :data:`TOPOLOGIES`.
    damping : str
        One of :data:`DAMPING_KINDS`.
    close_modes : bool
        Drawn as a mistuned symmetric structure (nearly repeated modes).
    springs : tuple of (int, int)
        Spring end DOFs; :data:`GROUND` for a spring to ground.
    M, C, K : ndarray, shape (n, n)
        Mass [kg], damping [N s/m] and stiffness [N/m] matrices of the underlying linear
        structure.
    elements : tuple of Element
        Nonlinear elements (none: a linear structure).
    """

    topology: str
    damping: str
    close_modes: bool
    springs: tuple[tuple[int, int], ...]
    M: np.ndarray
    C: np.ndarray
    K: np.ndarray
    elements: tuple[Element, ...] = ()

    @property
    def n_dofs(self) -> int:
        """Number of degrees of freedom n."""
        return int(self.M.shape[0])


def first_order(M: np.ndarray, C: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A (2n, 2n) and B (2n, n) of x' = A x + B f with the state x = [q; q'].

    Parameters
    ----------
    M, C, K : ndarray, shape (n, n)
    """
    n = M.shape[0]
    A = np.block([[np.zeros((n, n)), np.eye(n)],
                  [-np.linalg.solve(M, K), -np.linalg.solve(M, C)]])
    return A, np.vstack([np.zeros((n, n)), np.linalg.inv(M)])


def modes(M: np.ndarray, C: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Continuous-time poles and displacement mode shapes of M x'' + C x' + K x = f.

    Parameters
    ----------
    M, C, K : ndarray, shape (n, n)

    Returns
    -------
    poles : ndarray, shape (n,), complex
        One pole per underdamped mode (positive imaginary part), by natural frequency
        |s| / (2 pi) [Hz] ascending; the damping ratio is -Re s / |s|.
    shapes : ndarray, shape (n, n), complex
        Column r is the displacement shape psi_r of pole r.

    Raises
    ------
    ValueError
        When a mode is overdamped (the generator must never draw one).
    """
    n = M.shape[0]
    values, vectors = np.linalg.eig(first_order(M, C, K)[0])
    upper = values.imag > 0
    if upper.sum() != n:
        raise ValueError("overdamped or real mode in the structure; redraw its damping")
    values, vectors = values[upper], vectors[:n, upper]
    order = np.argsort(np.abs(values))
    return values[order], vectors[:, order]


def frequencies_damping(poles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Natural frequencies [Hz] and damping ratios [-] of continuous-time poles."""
    return np.abs(poles) / (2 * np.pi), -poles.real / np.abs(poles)


def log_uniform(rng: np.random.Generator, low: float, high: float, size=None):
    """Draw(s) whose logarithm is uniform between log(low) and log(high)."""
    return np.exp(rng.uniform(np.log(low), np.log(high), size))


def _stiffness(n: int, springs, k: np.ndarray) -> np.ndarray:
    """Assembled matrix of springs (or dashpots) with constants ``k``."""
    K = np.zeros((n, n))
    for (a, b), value in zip(springs, k, strict=True):
        K[a, a] += value
        if b != GROUND:
            K[b, b] += value
            K[a, b] -= value
            K[b, a] -= value
    return K


def _chain(n: int, rng: np.random.Generator) -> list[tuple[int, int]]:
    springs = [(0, GROUND)] + [(j, j - 1) for j in range(1, n)]
    if rng.random() < 0.3:
        springs.append((n - 1, GROUND))
    return springs


def _tree(n: int, rng: np.random.Generator) -> list[tuple[int, int]]:
    springs = [(0, GROUND)] + [(j, int(rng.integers(j))) for j in range(1, n)]
    if n > 2 and rng.random() < 0.3:
        springs.append((int(rng.integers(1, n)), GROUND))
    return springs


def _grid(n: int, rng: np.random.Generator) -> list[tuple[int, int]]:
    """Row-major grid of ceil(n / rows) columns, the last row possibly short; springs to
    the right and lower neighbours, to ground along the first column and at random."""
    rows = max(1, int(np.floor(np.sqrt(n))))
    cols = int(np.ceil(n / rows))
    springs = []
    for j in range(n):
        c = j % cols
        if c + 1 < cols and j + 1 < n:
            springs.append((j + 1, j))
        if j + cols < n:
            springs.append((j + cols, j))
        if c == 0 or rng.random() < 0.2:
            springs.append((j, GROUND))
    return springs


def _symmetric(n: int, topology: str, rng: np.random.Generator,
               ) -> tuple[list[tuple[int, int]], np.ndarray, np.ndarray]:
    """Springs, nominal masses and stiffnesses of a symmetric structure (repeated or
    nearly repeated modes once mistuned).

    chain: two equal grounded chains joined end to end by a weak spring (an odd DOF hangs
    off the joint); tree: a grounded hub carrying two or three equal branches; grid: a
    square grid (4 or 9 DOFs, the nearest to n) with every mass grounded alike.
    """
    if topology == "grid":
        side = 2 if n < 7 else 3
        n = side * side
        springs = [(j, GROUND) for j in range(n)]
        springs += [(j + 1, j) for j in range(n) if (j + 1) % side]
        springs += [(j + side, j) for j in range(n - side)]
        k = np.concatenate([np.full(n, log_uniform(rng, 0.2, 1.0)), np.ones(len(springs) - n)])
        return springs, np.ones(n), k
    if topology == "chain":
        half = n // 2
        masses = log_uniform(rng, 0.5, 2.0, half)
        stiff = log_uniform(rng, 0.5, 2.0, half)
        springs = [(0, GROUND)] + [(j, j - 1) for j in range(1, half)]
        springs += [(half, GROUND)] + [(half + j, half + j - 1) for j in range(1, half)]
        k = np.concatenate([stiff, stiff, [log_uniform(rng, 0.02, 0.2)]])
        springs.append((half - 1, 2 * half - 1))
        m = np.concatenate([masses, masses])
        if n % 2:
            springs.append((n - 1, half - 1))
            k = np.append(k, log_uniform(rng, 0.5, 2.0))
            m = np.append(m, log_uniform(rng, 0.5, 2.0))
        return springs, m, k
    branches = 2 if (n - 1) % 3 or n < 4 else 3
    length = max(1, (n - 1) // branches)
    masses = log_uniform(rng, 0.5, 2.0, length)
    stiff = log_uniform(rng, 0.5, 2.0, length)
    springs, m, k = [(0, GROUND)], [log_uniform(rng, 1.0, 4.0)], [log_uniform(rng, 0.5, 2.0)]
    for _ in range(branches):
        start = len(m)
        for j in range(length):
            springs.append((start + j, 0 if j == 0 else start + j - 1))
        m.extend(masses)
        k.extend(stiff)
    while len(m) < n:  # leftover DOFs extend the hub
        springs.append((len(m), 0))
        m.append(log_uniform(rng, 0.5, 2.0))
        k.append(log_uniform(rng, 0.5, 2.0))
    return springs, np.array(m), np.array(k)


def _proportional(M: np.ndarray, K: np.ndarray, zeta: np.ndarray) -> np.ndarray:
    """Damping matrix with classical normal modes of damping ratios ``zeta`` (ascending
    natural frequency): C = M Phi diag(2 zeta omega) Phi^T M, Phi mass-normalised."""
    omega2, phi = scipy.linalg.eigh(K, M)
    return M @ phi @ np.diag(2 * zeta * np.sqrt(omega2)) @ phi.T @ M


def draw_structure(rng: np.random.Generator, n: int, topology: str, *, close_modes: bool,
                   proportional: bool, first_frequency: float) -> Structure:
    """A random structure of ``n`` DOFs (the symmetric grid takes 4 or 9).

    Masses and spring constants are log-uniform over a factor 4; a close-mode structure is
    symmetric and mistuned by 0.5-3 % (its nearly repeated modes split by about that
    much). Damping: a level zeta_0 log-uniform in :data:`DAMPING_RANGE`, each mode within a
    factor 1.5 of it (clipped to the range); non-proportional damping mixes in dashpots on
    20-60 % of the springs with the same mean modal damping (weight 0.3-1), the weight
    halved until every mode is in :data:`DAMPING_RANGE` again.

    Parameters
    ----------
    rng : numpy.random.Generator
    n : int
        DOFs, 2-12.
    topology : str
        One of :data:`TOPOLOGIES`.
    close_modes, proportional : bool
    first_frequency : float
        Lowest natural frequency of the undamped structure [Hz].

    Returns
    -------
    Structure
    """
    if close_modes:
        springs, m, k = _symmetric(n, topology, rng)
        mistune = rng.uniform(0.005, 0.03)
        m = m * (1 + mistune * rng.uniform(-1, 1, m.size))
        k = k * (1 + mistune * rng.uniform(-1, 1, k.size))
    else:
        springs = {"chain": _chain, "tree": _tree, "grid": _grid}[topology](n, rng)
        m = log_uniform(rng, 0.5, 2.0, n)
        k = log_uniform(rng, 0.5, 2.0, len(springs))
    n = m.size
    M, K = np.diag(m), _stiffness(n, springs, k)
    omega2 = scipy.linalg.eigvalsh(K, M)
    K = K * (2 * np.pi * first_frequency) ** 2 / omega2[0]
    omega = np.sqrt(scipy.linalg.eigvalsh(K, M))
    level = log_uniform(rng, *DAMPING_RANGE)
    zeta = np.clip(level * log_uniform(rng, 1 / 1.5, 1.5, n), *DAMPING_RANGE)
    C = _proportional(M, K, zeta)
    if not proportional:
        chosen = rng.random(len(springs)) < rng.uniform(0.2, 0.6)
        chosen[rng.integers(len(springs))] = True
        c = np.where(chosen, log_uniform(rng, 0.25, 4.0, len(springs)), 0.0)
        dashpots = _stiffness(n, springs, c * k / k.mean())
        # scaled to the proportional part's mean modal damping 2 zeta omega
        _, phi = scipy.linalg.eigh(K, M)
        modal = np.diag(phi.T @ dashpots @ phi)
        dashpots *= np.mean(2 * zeta * omega) / np.mean(modal)
        weight = rng.uniform(0.3, 1.0)
        while weight >= 0.01:
            mixed = (1 - weight) * C + weight * dashpots
            _, ratios = frequencies_damping(modes(M, mixed, K)[0])
            if np.all((ratios >= DAMPING_RANGE[0]) & (ratios <= DAMPING_RANGE[1])):
                C = mixed
                break
            weight /= 2
        else:  # no mixture kept every mode in range: the structure stays proportional
            proportional = True
    return Structure(topology, "proportional" if proportional else "nonproportional",
                     close_modes, tuple(springs), M, C, K)
