"""Gaussian radial basis features on regular grids (paper Sec. III-B and III-C).

The innate and the view module code their state with Gaussian radial basis functions (RBFs)::

    b_j(x) = exp(-sum_k (x_k - x_{j,k})^2 / phi_k)            paper III-B, III-C

with the centres ``x_j`` on a regular grid (the Cartesian product of one set of centres per
input dimension), so ``b`` is the outer product of one 1-D Gaussian profile per dimension. The
paper uses a single width ``phi`` for the 2-D view state ``(theta_d, d_o)``, whose components
have different units; here every dimension has its own ``phi_k`` (our choice, paper silent).
A dimension may be periodic (an angle): its distance to a centre is then wrapped to (-pi, pi].

One more feature, the *not visible* feature, is 1 when the destination is not seen (a NaN in
the input) and then every RBF is 0: ``b = e_n`` (paper: "one basis function is considered to
represent the situation when the destination gets out of sight").

Optionally the RBF part is normalised to sum to 1 (``normalize``): the value ``w^T b`` and the
policy mean ``W b`` then interpolate the weights of the nearest centres, and a constant weight
vector gives a constant value (our choice; the paper's RBFs are not normalised).
"""

from __future__ import annotations

from collections.abc import Sequence
import math

from clis_base.ufunc_loops import LOOPS, exp_into, pairwise_sum
from cr_sim.core.geometry import TWO_PI, wrap_angles
from cr_sim.core.kernels import njit
import numpy as np
from numpy.typing import ArrayLike

__all__ = ['uniform_centers', 'RbfGrid']


def uniform_centers(lo: float, hi: float, n: int, periodic: bool) -> np.ndarray:
    """Centres of ``n`` RBFs spread uniformly over ``[lo, hi]``.

    Parameters
    ----------
    lo, hi : float
        Range of the input.
    n : int
        Number of centres, >= 1.
    periodic : bool
        For a periodic input (``lo`` and ``hi`` are the same point) the centres are the middles
        of ``n`` equal bins, ``lo + (hi - lo) (k + 1/2) / n``: no two coincide, and for an odd
        ``n`` over ``[-pi, pi]`` one sits at 0 (straight ahead). Otherwise ``linspace(lo, hi,
        n)`` (both ends included; the middle for ``n = 1``).

    Returns
    -------
    np.ndarray, shape (n,)
    """
    if n < 1:
        raise ValueError(f'need at least one centre, got n = {n}')
    if periodic:
        return lo + (hi - lo) * (np.arange(n) + 0.5) / n
    if n == 1:
        return np.array([0.5 * (lo + hi)])
    return np.linspace(lo, hi, n)


class RbfGrid:
    """Separable Gaussian RBFs on a grid of centres, plus the *not visible* feature.

    Parameters
    ----------
    centers : sequence of array_like
        One 1-D array of centres per input dimension, lengths ``n_1 .. n_D``.
    phi : sequence of float
        Width ``phi_k`` of each dimension, in the squared unit of that input (rad^2, m^2).
    periodic : sequence of bool
        Whether each dimension is an angle (distance wrapped to (-pi, pi]).
    normalize : bool
        Scale the RBF part to sum to 1.

    Attributes
    ----------
    n : int
        Number of features, ``n_1 * ... * n_D + 1`` (the last one is *not visible*). The RBF of
        centre ``(c_1[i_1], .., c_D[i_D])`` is at the C-order (row-major) flat index.
    """

    def __init__(self, centers: Sequence[ArrayLike], phi: Sequence[float],
                 periodic: Sequence[bool], normalize: bool) -> None:
        self.centers = [np.asarray(c, dtype=np.float64).reshape(-1) for c in centers]
        self.phi = np.asarray(phi, dtype=np.float64).reshape(-1)
        self.periodic = tuple(bool(p) for p in periodic)
        if not (len(self.centers) == len(self.phi) == len(self.periodic) >= 1):
            raise ValueError('centers, phi and periodic need one entry per input dimension')
        if np.any(self.phi <= 0.0):
            raise ValueError(f'RBF widths phi must be > 0, got {self.phi}')
        self.normalize = bool(normalize)
        self.n_rbf = int(math.prod(len(c) for c in self.centers))
        self.n = self.n_rbf + 1
        self._flat_centers = np.concatenate(self.centers)
        self._sizes = np.array([len(c) for c in self.centers], dtype=np.int64)
        self._periodic = np.array(self.periodic, dtype=np.bool_)
        # scratch of __call__'s exponents: one call at a time per grid (each scheduler of the
        # project decides a module from one thread)
        self._q = np.empty(len(self._flat_centers))
        self._x = np.empty(len(self.centers))

    @property
    def dim(self) -> int:
        """Number of input dimensions D."""
        return len(self.centers)

    def batch(self, x: ArrayLike) -> np.ndarray:
        """Features of many inputs.

        Parameters
        ----------
        x : array_like, shape (N, D)
            Inputs; a row with any NaN means *not visible*.

        Returns
        -------
        np.ndarray, shape (N, n)
            ``b(x)`` per row: the RBFs then the *not visible* feature.
        """
        x = np.asarray(x, dtype=np.float64).reshape(-1, self.dim)
        blind = np.isnan(x).any(axis=1)
        out = np.ones((x.shape[0], 1))
        for k, c in enumerate(self.centers):
            d = x[:, k:k + 1] - c[None, :]                       # (N, n_k)
            if self.periodic[k]:
                d = wrap_angles(np.where(np.isnan(d), 0.0, d))
            q = (d * d) / self.phi[k]
            if self.normalize:
                # a per-row factor cancels in the normalisation: keeps far inputs finite
                q -= q.min(axis=1, keepdims=True)
            # b_j(x) = exp(-||x - x_j||^2 / phi), one dimension at a time (III-B, III-C)
            g = np.exp(-q)
            out = (out[:, :, None] * g[:, None, :]).reshape(x.shape[0], -1)
        if self.normalize:
            out /= out.sum(axis=1, keepdims=True)
        b = np.zeros((x.shape[0], self.n))
        b[:, :-1] = out
        b[blind, :-1] = 0.0
        b[blind, -1] = 1.0
        return b

    def __call__(self, x: ArrayLike) -> np.ndarray:
        """Features of one input ``x`` (shape (D,), NaN = not visible) -> shape (n,).

        The arithmetic of :meth:`batch` for one row, compiled (:func:`_rbf_exponents`,
        :func:`_rbf_products`) around numpy's exp: bit-identical results (tested), the hot
        path of every innate and view decision.
        """
        xs = np.asarray(x, dtype=np.float64).reshape(self.dim)
        if self.n_rbf > _PAIRWISE_BLOCK:
            return self.batch(xs[None, :])[0]
        return self.at(*xs.tolist())

    def at(self, *x: float) -> np.ndarray:
        """:meth:`__call__` of the input ``x`` given as D floats (no input array made): the
        features in one compiled call (:func:`_rbf_into`: the exponents, numpy's own exp
        loop, the products; the operations of :meth:`batch` for one row, bit for bit)."""
        if len(x) != len(self.centers):
            raise ValueError(f'expected {len(self.centers)} inputs, got {len(x)}')
        if self.n_rbf > _PAIRWISE_BLOCK:
            return self.batch(np.array([x], dtype=np.float64))[0]
        b = np.zeros(self.n)
        xs = self._x
        for k, v in enumerate(x):
            if v != v:                                   # NaN
                b[-1] = 1.0                              # not visible: b = e_n
                return b
            xs[k] = v
        # b_j(x) = exp(-||x - x_j||^2 / phi), one dimension at a time (III-B, III-C)
        _rbf_into(xs, self._flat_centers, self._sizes, self.phi, self._periodic,
                  self.normalize, self._q, LOOPS, b)
        return b


@njit
def _rbf_into(x: np.ndarray, centers: np.ndarray, sizes: np.ndarray, phi: np.ndarray,
              periodic: np.ndarray, normalize: bool, q: np.ndarray, loops: np.ndarray,
              b: np.ndarray) -> None:
    """``b[:-1]`` <- the RBFs of one input: :func:`_rbf_exponents` into ``q``, then
    ``exp(-q)`` (numpy's loop: :func:`clis_base.ufunc_loops.exp_into`), then
    :func:`_rbf_products`."""
    _rbf_exponents(x, centers, sizes, phi, periodic, normalize, q)
    n = q.shape[0]
    for j in range(n):
        q[j] = -q[j]
    exp_into(loops, q, q, n)
    _rbf_products(q, sizes, normalize, b)


@njit
def _rbf_exponents(x: np.ndarray, centers: np.ndarray, sizes: np.ndarray, phi: np.ndarray,
                   periodic: np.ndarray, normalize: bool, q: np.ndarray) -> None:
    """``q`` <- ``(x_k - c_kj)^2 / phi_k`` per dimension k (distance wrapped where periodic,
    as :func:`~cr_sim.core.geometry.wrap_angles`; minus its smallest value per dimension when
    ``normalize``), concatenated: shape (sum n_k,) (written in place: a kernel that returns
    a new array pays for boxing it at every call)."""
    start = 0
    for k in range(sizes.shape[0]):
        stop = start + sizes[k]
        for j in range(start, stop):
            d = x[k] - centers[j]
            if periodic[k]:
                r = (np.pi - d) % TWO_PI          # numpy's remainder (Python float %)
                if r >= TWO_PI:
                    r = 0.0
                d = np.pi - r
            q[j] = (d * d) / phi[k]
        if normalize:
            low = q[start]
            for j in range(start + 1, stop):
                low = min(low, q[j])
            for j in range(start, stop):
                q[j] -= low
        start = stop


#: Grids up to this many RBFs: one input's features compiled (numpy's block size).
_PAIRWISE_BLOCK = 128


@njit
def _rbf_products(g: np.ndarray, sizes: np.ndarray, normalize: bool, b: np.ndarray) -> None:
    """``b[:-1]`` <- the outer product of the per-dimension profiles ``g`` (concatenated),
    C order, divided by its sum when ``normalize``."""
    n_rbf = b.shape[0] - 1
    out = np.empty(n_rbf)
    out[:sizes[0]] = g[:sizes[0]]
    n, start = sizes[0], sizes[0]
    for k in range(1, sizes.shape[0]):
        m = sizes[k]
        prev = out[:n].copy()
        for i in range(n):
            for j in range(m):
                out[i * m + j] = prev[i] * g[start + j]
        n *= m
        start += m
    if normalize:
        total = pairwise_sum(out, 0, n_rbf)      # np.sum's order
        for i in range(n_rbf):
            out[i] /= total
    b[:n_rbf] = out
