"""The three CLIS modules (paper III-B..D, docs/design.md §1 and 3) and their parameters.

Every module is a :class:`ModuleCore`: features ``b_i(x)`` of its own state, a Gaussian policy
(10) ``u ~ N(v_max W_i b, sigma_i^2 I)`` over ``u = (v_left, v_right)`` [m/s], a linear value
``V_i = w_i^T b`` (1)(2), a decision period ``tau_i`` with its discount ``gamma_i`` (11) and
speed limit ``v_max,i``.

==========  ============================================  ==========================  =========
module      features b (n)                                policy                      period
==========  ============================================  ==========================  =========
innate      9 periodic RBFs over theta_d + not visible    fixed, hand-made            250 ms
view        9 x 9 RBFs over (theta_d, d_o) + not visible  learned by (9)              500 ms
place       belief of the grid Markov localization        learned by (9)              1200 ms
==========  ============================================  ==========================  =========

Speed limit (docs/design.md §3): a module deciding every ``tau_i`` may drive at most
``v_max,i = min(v_wheel_max, d_react / tau_i)``, so it moves at most ``d_react`` between two
decisions. Policy means are ``v_max,i W b`` (W dimensionless); the runner clamps the executed
command to ``v_max,i``; densities are of the proposed (pre-clamp) action.

Discount (11): ``gamma_i = gamma^(tau_i / base_tick)``. The paper prints ``gamma^{tau_i'}``;
we read the exponent as the number of base ticks in a module's period (docs/design.md §2), so one
second is discounted alike by every module and all optimise the same objective.

The innate policy (paper III-B: "moves to the destination directly ... if the destination is
not observed, it generates random action") is hand-made as a target mean

    s = clip(theta_d / turn_angle, -1, 1),   a = forward (1 - |s|)
    mu*(theta_d) = v_max (a - s,  a + s)                          (v_left, v_right)

(straight ahead at ``forward v_max`` when aligned, the wheel-speed difference proportional to
the bearing, turning in place at full speed beyond ``turn_angle``; ``|mu*| <= v_max``. Since
``v_max tau = d_react``, the heading change per decision, ``2 s d_react / wheel_base``, is the
same whatever the period: about 1.2 theta_d with the defaults, a stable correction), written in
the module's own features: ``W_in`` is the
least-squares fit of ``mu* / v_max`` on the RBFs over a dense grid of theta_d, and the *not
visible* column is the blind mean ``blind_forward v_max`` on both wheels, with the wider
``sigma_blind``. So the innate module is the same linear-Gaussian object as the learned ones
(same density and sampling code), only never updated by (9).
"""

from __future__ import annotations

from collections.abc import Sequence
import math
from typing import Any, Protocol

from cr_sim.core.params import dataclass, load_params, param
import numpy as np
from numpy.typing import ArrayLike
import scipy.sparse

from clis_modules.core.arbiter import ArbiterParams
from clis_modules.core.features import RbfGrid, uniform_centers
from clis_modules.core.localization import LocalizationParams, MarkovLocalizer
from clis_modules.core.policy import GaussianPolicy
from clis_modules.core.value import LinearValue, gamma_i

__all__ = [
    'CONDITIONS', 'MODULE_NAMES', 'CommonParams', 'ValueParams', 'PolicyParams', 'InnateParams',
    'ViewParams', 'PlaceParams', 'PlaceFeatureParams', 'PLACE_FEATURES', 'place_projection',
    'ModuleSetParams', 'load_module_params', 'ModuleCore',
    'speed_limit', 'module_gamma', 'condition_periods', 'innate_target_mean', 'make_innate',
    'make_view', 'make_place', 'make_modules', 'make_module', 'arena_map',
]

#: Module names, in the canonical order (index = module id in memories and diagnostics).
MODULE_NAMES = ('innate', 'view', 'place')
#: ``place.features.kind``: the belief itself, or projected onto RBFs over the pose.
PLACE_FEATURES = ('belief', 'rbf')
#: Experimental conditions of the paper (Sec. IV).
CONDITIONS = ('innate', 'view', 'place', 'sync', 'async')


# ------------------------------------------------------------------------------ parameters

@dataclass(frozen=True)
class CommonParams:
    """Shared by every module (``clis.yaml`` section ``common``)."""

    gamma: float = param(0.0, 1.0, doc='common discount rate gamma per base tick, (11)')
    base_tick: float = param(1e-3, 10.0, doc='base tick Delta of (11) [s]')
    beta: float = param(0.0, 1e6, doc='inverse temperature beta of the selection (3)')
    epsilon: float = param(0.0, 1e6, doc='constant epsilon of the truncated ratio (7)')
    d_react: float = param(1e-3, 10.0, doc='distance allowed between decisions [m]')
    v_wheel_max: float = param(0.01, 1.3, doc='hard limit of each wheel [m/s]')


@dataclass(frozen=True)
class ValueParams:
    """Linear value (1)(2) and its TD(lambda) learning (8) (section ``<module>.value``)."""

    alpha: float = param(0.0, 10.0, doc='step size alpha_i of TD(lambda) (8)')
    v_init: float = param(-100.0, 100.0, doc='initial weight of every value feature')


@dataclass(frozen=True)
class PolicyParams:
    """Learned Gaussian policy (10) and its gradient learning (9) (``<module>.policy``)."""

    alpha: float = param(0.0, 10.0, doc='step size alpha_i of the policy gradient (9)')
    sigma: float = param(1e-3, 5.0, doc='initial std sigma_i of each wheel [m/s]')
    learn_sigma: bool = param(doc='also learn sigma_i by (9)')
    sigma_min: float = param(1e-3, 5.0, doc='lower bound of a learned sigma_i [m/s]')
    sigma_max: float = param(1e-3, 5.0, doc='upper bound of a learned sigma_i [m/s]')
    alpha_sigma: float = param(0.0, 10.0, doc='step size of sigma_i in (9)')

    def validate(self) -> None:
        """``sigma_min <= sigma <= sigma_max``."""
        if not self.sigma_min <= self.sigma <= self.sigma_max:
            raise ValueError(f'need sigma_min <= sigma <= sigma_max, got {self.sigma_min}, '
                             f'{self.sigma}, {self.sigma_max}')


@dataclass(frozen=True)
class InnateParams:
    """The innate module M_in (section ``innate``, paper III-B)."""

    period: float = param(0.01, 60.0, doc='decision period tau_in [s]')
    n_rbf: int = param(1, 1000, doc='number of RBFs over theta_d')
    phi: float = param(1e-6, 100.0, doc='RBF width phi_in [rad^2]')
    normalize: bool = param(doc='normalise the RBFs to sum 1')
    value: ValueParams = param(doc='section innate.value')
    forward: float = param(0.0, 1.0, doc='forward speed when aligned, fraction of v_max')
    turn_angle_deg: float = param(1.0, 180.0, doc='bearing beyond which it turns in place [deg]')
    sigma: float = param(1e-3, 5.0, doc='std of each wheel when the destination is seen [m/s]')
    blind_forward: float = param(-1.0, 1.0, doc='mean wheel speed when not seen, x v_max')
    sigma_blind: float = param(1e-3, 5.0, doc='std of each wheel when not seen [m/s]')


@dataclass(frozen=True)
class ViewParams:
    """The view-based module M_vi (section ``view``, paper III-C)."""

    period: float = param(0.01, 60.0, doc='decision period tau_vi [s]')
    n_theta: int = param(1, 100, doc='number of RBF centres over theta_d')
    n_dist: int = param(1, 100, doc='number of RBF centres over d_o')
    phi_theta: float = param(1e-6, 100.0, doc='RBF width over theta_d [rad^2]')
    phi_dist: float = param(1e-8, 100.0, doc='RBF width over d_o [m^2]')
    d_max: float = param(0.01, 10.0, doc='largest d_o centre [m] (the IR range)')
    normalize: bool = param(doc='normalise the RBFs to sum 1')
    value: ValueParams = param(doc='section view.value')
    policy: PolicyParams = param(doc='section view.policy')


@dataclass(frozen=True)
class PlaceFeatureParams:
    """What the place module's linear value (1) and policy (10) read of its belief (section
    ``place.features``; the paper is silent beyond "b_pl,j(x) denotes the robot's belief")."""

    kind: str = param(choices=PLACE_FEATURES,
                      doc="'belief' = the belief over the grid cells itself (paper III-D); "
                          "'rbf' = the belief projected onto Gaussian RBFs over (x, y, theta), "
                          'b_k = sum_cells belief(cell) phi_k(cell), which generalise across '
                          'neighbouring cells (our choice)')
    n_xy: int = param(1, 100, doc="RBF centres per axis of the floor ('rbf')")
    n_theta: int = param(1, 100, doc="RBF centres over the heading ('rbf')")
    phi_xy: float = param(1e-6, 100.0, doc="RBF width over x and y [m^2] ('rbf')")
    phi_theta: float = param(1e-6, 100.0, doc="RBF width over the heading [rad^2] ('rbf')")


@dataclass(frozen=True)
class PlaceParams:
    """The place-based module M_pl (section ``place``, paper III-D)."""

    period: float = param(0.01, 60.0, doc='decision period tau_pl [s]')
    localization: LocalizationParams = param(doc='section place.localization')
    features: PlaceFeatureParams = param(doc='section place.features')
    value: ValueParams = param(doc='section place.value')
    policy: PolicyParams = param(doc='section place.policy')


@dataclass(frozen=True)
class ModuleSetParams:
    """The sections of ``config/clis.yaml`` that the modules and the arbiter read (the learner
    reads them too, plus its own: ``clis_learner.core.config.ClisParams``)."""

    common: CommonParams = param(doc='section common')
    innate: InnateParams = param(doc='section innate')
    view: ViewParams = param(doc='section view')
    place: PlaceParams = param(doc='section place')
    arbiter: ArbiterParams = param(doc='section arbiter')


def load_module_params(path: str | None = None, overrides: dict | None = None
                       ) -> ModuleSetParams:
    """:class:`ModuleSetParams` from ``/**: ros__parameters:`` of ``clis.yaml`` (or ``path``),
    validated (a bad value raises ``ConfigError`` naming the file and the dotted key)."""
    return load_params(ModuleSetParams, 'clis.yaml', '/**', path, overrides,
                       ignore=('learner',))


class ModuleParamsLike(Protocol):
    """What :func:`make_modules` reads (``clis_learner.core.config.ClisParams`` has it)."""

    common: CommonParams
    innate: InnateParams
    view: ViewParams
    place: PlaceParams


# ------------------------------------------------------------------------------ helpers

def speed_limit(common: CommonParams, period: float) -> float:
    """``v_max,i = min(v_wheel_max, d_react / tau_i)`` [m/s] (docs/design.md §3)."""
    return min(common.v_wheel_max, common.d_react / period)


def module_gamma(common: CommonParams, period: float) -> float:
    """Semi-MDP discount of a module with period ``period``, eq. (11) (:func:`gamma_i`)."""
    return gamma_i(common.gamma, period, common.base_tick)


def condition_periods(params: ModuleParamsLike, condition: str) -> list[tuple[str, float]]:
    """``(name, tau_i)`` of the modules of a condition (paper IV, docs/design.md §3): one module
    on its own period, all three on their own periods (``async``) or all on the slowest one
    (``sync``); in the order innate, view, place."""
    if condition not in CONDITIONS:
        raise ValueError(f'unknown condition {condition!r}: choose from {", ".join(CONDITIONS)}')
    own = {'innate': params.innate.period, 'view': params.view.period,
           'place': params.place.period}
    names: Sequence[str] = MODULE_NAMES if condition in ('sync', 'async') else (condition,)
    if condition == 'sync':
        return [(name, max(own.values())) for name in names]
    return [(name, own[name]) for name in names]


def innate_target_mean(theta_d: ArrayLike, forward: float, turn_angle: float) -> np.ndarray:
    """Hand-made innate mean ``mu* / v_max`` (module docstring), shape (N, 2).

    Parameters
    ----------
    theta_d : array_like, shape (N,)
        Bearing of the destination [rad], counter-clockwise positive.
    forward : float
        Forward wheel speed when aligned, as a fraction of ``v_max``.
    turn_angle : float
        Bearing [rad] beyond which the robot turns in place.
    """
    s = np.clip(np.asarray(theta_d, dtype=np.float64) / turn_angle, -1.0, 1.0)
    a = forward * (1.0 - np.abs(s))
    return np.stack([a - s, a + s], axis=-1)


# ------------------------------------------------------------------------------ the module

class ModuleCore:
    """One CLIS module: features, Gaussian policy (10), linear value (1)(2), period.

    Parameters
    ----------
    name : str
    period : float
        Decision period ``tau_i`` [s].
    gamma : float
        Discount per decision ``gamma_i`` (11).
    v_max : float
        Speed limit [m/s].
    n : int
        Number of features.
    feature_fn : callable
        ``feature_fn(dest_bearing, d_o, landmark_bearings) -> b`` of shape (n,).
    policy : GaussianPolicy
    value : LinearValue
    value_params : ValueParams
    policy_params : PolicyParams, optional
        ``None`` for a fixed policy (``learned`` is False).
    localizer : MarkovLocalizer, optional
        The place module's localization (driven by the runner).
    belief_features : callable, optional
        With a localizer: ``belief_features(belief) -> b`` of shape (n,), the features of any
        belief (of :meth:`MarkovLocalizer.peek` too); ``feature_fn`` is it applied to the
        localizer's current belief. Default: the belief itself.

    Attributes
    ----------
    learned : bool
        Whether the policy is learned by (9) (view, place) or fixed (innate).
    """

    def __init__(self, name: str, period: float, gamma: float, v_max: float, n: int,
                 feature_fn: Any, policy: GaussianPolicy, value: LinearValue,
                 value_params: ValueParams, policy_params: PolicyParams | None = None,
                 localizer: MarkovLocalizer | None = None,
                 belief_features: Any = None) -> None:
        self.name = name
        self.belief_features = belief_features or (lambda belief: belief.copy())
        self.period = float(period)
        self.gamma = float(gamma)
        self.v_max = float(v_max)
        self.n = int(n)
        self._feature_fn = feature_fn
        self.policy = policy
        self.value_fn = value
        self.value_params = value_params
        self.policy_params = policy_params
        self.localizer = localizer
        self.learned = policy_params is not None

    def __repr__(self) -> str:
        return (f'ModuleCore({self.name!r}, period={self.period}, gamma={self.gamma:.6f}, '
                f'v_max={self.v_max:.4f}, n={self.n}, learned={self.learned})')

    # parameters (checkpointed) ---------------------------------------------------------

    @property
    def w(self) -> np.ndarray:
        """Value weights ``w_i``, shape (n,)."""
        return self.value_fn.w

    @w.setter
    def w(self, value: ArrayLike) -> None:
        self.value_fn.w = _checked(value, (self.n,), f'{self.name}.w')

    @property
    def W(self) -> np.ndarray:  # noqa: N802 - the paper's W_i
        """Policy mean weights ``W_i``, shape (2, n) (mean = ``v_max W b``)."""
        return self.policy.W

    @W.setter
    def W(self, value: ArrayLike) -> None:  # noqa: N802
        self.policy.W = _checked(value, (2, self.n), f'{self.name}.W')

    @property
    def sigma(self) -> float:
        """Policy std ``sigma_i`` [m/s] (when the destination is seen, for the innate)."""
        return self.policy.sigma

    @sigma.setter
    def sigma(self, value: float) -> None:
        value = float(value)
        if not (value > 0.0 and math.isfinite(value)):
            raise ValueError(f'{self.name}.sigma must be a positive number, got {value}')
        self.policy.sigma = value

    # per episode / per decision ---------------------------------------------------------

    def reset(self) -> None:
        """Episode start: the place module forgets its pose (uniform belief)."""
        if self.localizer is not None:
            self.localizer.reset()

    def features(self, dest_bearing: float = math.nan, d_o: float = math.nan,
                 landmark_bearings: ArrayLike | None = None) -> np.ndarray:
        """Features ``b_i(x)`` of the current observation, shape (n,) (a fresh array).

        Parameters
        ----------
        dest_bearing : float
            Bearing of the destination relative to the heading [rad]; NaN = not seen.
        d_o : float
            Distance to the nearest obstacle from the IR [m].
        landmark_bearings : array_like, shape (4,), optional
            Unused by the modules themselves: the place module's features are the current
            belief of its :attr:`localizer`, which the runner updates first
            (``localizer.predict`` then ``localizer.update(landmark_bearings)``).
        """
        return self._feature_fn(dest_bearing, d_o, landmark_bearings)

    def policy_mean(self, b: ArrayLike) -> np.ndarray:
        """Mean action ``v_max W b`` [m/s], shape (2,)."""
        return self.policy.mean(b)

    def sample(self, b: ArrayLike, rng: np.random.Generator) -> np.ndarray:
        """Proposed action ``u ~ pi_i(b, .)`` [m/s], shape (2,), not clamped."""
        return self.policy.sample(b, rng)

    def density(self, b: ArrayLike, u: ArrayLike) -> float:
        """``pi_i(b, u)`` of (10) [(m/s)^-2]."""
        return self.policy.density(b, u)

    def value(self, b: ArrayLike) -> float:
        """``V_i = w_i^T b`` (1)(2)."""
        return self.value_fn(b)


def _checked(value: ArrayLike, shape: tuple[int, ...], what: str) -> np.ndarray:
    a = np.array(value, dtype=np.float64)
    if a.shape != shape:
        raise ValueError(f'{what} must have shape {shape}, got {a.shape}')
    if not np.all(np.isfinite(a)):
        raise ValueError(f'{what} holds non-finite values')
    return a


# ------------------------------------------------------------------------------ factories

def _theta_grid(n: int) -> np.ndarray:
    return uniform_centers(-math.pi, math.pi, n, periodic=True)


def make_innate(prm: InnateParams, common: CommonParams,
                period: float | None = None) -> ModuleCore:
    """The innate module M_in (paper III-B) with period ``period`` (default its own)."""
    tau = prm.period if period is None else period
    v_max = speed_limit(common, tau)
    grid = RbfGrid([_theta_grid(prm.n_rbf)], [prm.phi], [True], prm.normalize)
    # hand-made policy written in the module's features: least squares over a dense grid
    theta = np.linspace(-math.pi, math.pi, 721)
    b = grid.batch(theta[:, None])[:, :-1]
    target = innate_target_mean(theta, prm.forward, math.radians(prm.turn_angle_deg))
    fit, *_ = np.linalg.lstsq(b, target, rcond=None)                   # (n_rbf, 2)
    W = np.empty((2, grid.n))  # noqa: N806 - the paper's W
    W[:, :-1] = fit.T
    W[:, -1] = prm.blind_forward
    return ModuleCore(
        'innate', tau, module_gamma(common, tau), v_max, grid.n,
        lambda dest, d_o, lm: grid.at(dest),
        GaussianPolicy(W, prm.sigma, v_max, sigma_blind=prm.sigma_blind),
        LinearValue(grid.n, prm.value.v_init), prm.value)


def make_view(prm: ViewParams, common: CommonParams, period: float | None = None) -> ModuleCore:
    """The view-based module M_vi (paper III-C) with period ``period`` (default its own)."""
    tau = prm.period if period is None else period
    v_max = speed_limit(common, tau)
    grid = RbfGrid([_theta_grid(prm.n_theta), uniform_centers(0.0, prm.d_max, prm.n_dist, False)],
                   [prm.phi_theta, prm.phi_dist], [True, False], prm.normalize)

    def feature_fn(dest: float, d_o: float, lm: Any) -> np.ndarray:
        # not visible -> e_n whatever d_o is (paper III-C)
        return grid.at(dest, d_o if math.isfinite(dest) else 0.0)

    return ModuleCore(
        'view', tau, module_gamma(common, tau), v_max, grid.n, feature_fn,
        GaussianPolicy(np.zeros((2, grid.n)), prm.policy.sigma, v_max),
        LinearValue(grid.n, prm.value.v_init), prm.value, prm.policy)


def make_place(prm: PlaceParams, common: CommonParams, landmarks_xy: ArrayLike,
               half_size: float, boxes: ArrayLike | None = None,
               period: float | None = None) -> ModuleCore:
    """The place-based module M_pl (paper III-D) with its own Markov localizer.

    Its features are the belief ``b_pl`` itself (``place.features.kind = belief``, one per grid
    cell), or ``P b_pl`` (``rbf``): the belief-weighted mean of normalised Gaussian RBFs over
    the cells' poses ``(x, y, theta)``, ``P[k, c] = phi_k(pose_c)`` with ``sum_k P[k, c] = 1``,
    so a localised belief activates the RBFs around its cell and what is learned at one cell
    carries to its neighbours.
    """
    tau = prm.period if period is None else period
    v_max = speed_limit(common, tau)
    loc = MarkovLocalizer(prm.localization, landmarks_xy, half_size, boxes)
    fp = prm.features
    if fp.kind == 'rbf':
        P = place_projection(loc, fp)  # noqa: N806 - (n_rbf, cells)

        def belief_features(belief: np.ndarray) -> np.ndarray:
            return P @ belief
        n = P.shape[0]
    else:
        def belief_features(belief: np.ndarray) -> np.ndarray:
            return belief.copy()
        n = loc.size

    def feature_fn(dest: float, d_o: float, lm: Any) -> np.ndarray:
        return belief_features(loc.belief)
    return ModuleCore(
        'place', tau, module_gamma(common, tau), v_max, n, feature_fn,
        GaussianPolicy(np.zeros((2, n)), prm.policy.sigma, v_max),
        LinearValue(n, prm.value.v_init), prm.value, prm.policy, localizer=loc,
        belief_features=belief_features)


def place_projection(loc: MarkovLocalizer, fp: PlaceFeatureParams) -> scipy.sparse.csr_matrix:
    """``P`` of :func:`make_place`'s ``rbf`` features, shape (n_xy^2 n_theta, cells): column
    ``c`` the normalised RBFs at the centre pose of cell ``c`` (the belief's flat order,
    ``(heading, x, y)``)."""
    x0, x1 = loc.xs[0] - 0.5 * loc.cell, loc.xs[-1] + 0.5 * loc.cell
    y0, y1 = loc.ys[0] - 0.5 * loc.cell, loc.ys[-1] + 0.5 * loc.cell
    # centres in the middles of n equal bins of each axis (as for a periodic input)
    grid = RbfGrid([x0 + (x1 - x0) * (np.arange(fp.n_xy) + 0.5) / fp.n_xy,
                    y0 + (y1 - y0) * (np.arange(fp.n_xy) + 0.5) / fp.n_xy,
                    uniform_centers(-math.pi, math.pi, fp.n_theta, True)],
                   [fp.phi_xy, fp.phi_xy, fp.phi_theta], [False, False, True], normalize=True)
    th, gx, gy = np.meshgrid(loc.thetas, loc.xs, loc.ys, indexing='ij')
    poses = np.stack([gx.ravel(), gy.ravel(), th.ravel()], axis=1)    # flat order of belief
    P = grid.batch(poses)[:, :-1].T  # noqa: N806
    # sparse: activations below 1e-4 of a cell's mass dropped, each column renormalised to 1
    P[P < 1e-4] = 0.0
    return scipy.sparse.csr_matrix(P / P.sum(axis=0, keepdims=True))


def arena_map(arena: Any) -> tuple[np.ndarray, float, np.ndarray]:
    """What the modules know of an arena (``cr_sim.core.arena.Arena``): landmark positions
    (M, 2), the floor's half side [m], obstacle boxes (K, 4)."""
    landmarks = np.array([(lm.x, lm.y) for lm in arena.landmarks], dtype=np.float64)
    return landmarks, arena.floor(), np.array(arena.box_tuples(), dtype=np.float64)


def make_modules(params: ModuleParamsLike, condition: str, landmarks_xy: ArrayLike,
                 half_size: float, boxes: ArrayLike | None = None) -> list[ModuleCore]:
    """The modules of one experimental condition (paper Sec. IV, docs/design.md §3).

    Parameters
    ----------
    params : ClisParams
        Needs the sections ``common``, ``innate``, ``view`` and ``place``.
    condition : str
        ``'innate'``, ``'view'``, ``'place'`` (that module alone, own period), ``'sync'`` (all
        three on the slowest period, with that period's speed limit and gamma), ``'async'``
        (all three, own periods).
    landmarks_xy : array_like, shape (4, 2)
        Landmark positions [m], in the order of the observed bearings.
    half_size : float
        Half the side of the floor [m].
    boxes : array_like, shape (K, 4), optional
        Obstacles ``(xmin, ymin, xmax, ymax)`` [m] excluded from the localization grid.

    Returns
    -------
    list of ModuleCore
        In the order innate, view, place (those present).
    """
    return [make_module(params, name, period, landmarks_xy, half_size, boxes)
            for name, period in condition_periods(params, condition)]


def make_module(params: ModuleParamsLike, name: str, period: float, landmarks_xy: ArrayLike,
                half_size: float, boxes: ArrayLike | None = None) -> ModuleCore:
    """One module by name, with decision period ``period`` (:func:`condition_periods`);
    the other arguments as for :func:`make_modules`."""
    if name == 'innate':
        return make_innate(params.innate, params.common, period)
    if name == 'view':
        return make_view(params.view, params.common, period)
    if name == 'place':
        return make_place(params.place, params.common, landmarks_xy, half_size, boxes, period)
    raise ValueError(f'unknown module {name!r}: one of {", ".join(MODULE_NAMES)}')
