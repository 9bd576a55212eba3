"""The CLIS module common to every plug-in (paper II, docs/design.md §1 and 3), built from the
configuration's parameters (:mod:`clis_modules.core.module_params`: the shared sections, the
module instances and the conditions, whose names this module re-exports for its users).

Every module is a :class:`ModuleCore`: features ``b_i(x)`` of its own state, a Gaussian policy
(10) ``u ~ N(v_max W_i b, sigma_i^2 I)`` over ``u = (v_left, v_right)`` [m/s], a linear value
``V_i = w_i^T b`` (1)(2), a decision period ``tau_i`` with its discount ``gamma_i`` (11) and
speed limit ``v_max,i``.

A module's features, its initial policy and its state (if any) come from its plug-in
(:mod:`clis_modules.core.plugin`; the project's own in :mod:`clis_modules.plugins`):

==========  ============================================  ==========================  =========
module      features b (n)                                policy                      period
==========  ============================================  ==========================  =========
innate      9 periodic RBFs over theta_d + not visible    fixed, hand-made            250 ms
view        9 x 9 RBFs over (theta_d, d_o) + not visible  learned by (9)              500 ms
place       belief of the grid Markov localization        learned by (9)              1200 ms
wall        RBFs over the 7 IR rays x theta_d (ours)      learned by (9)              750 ms
==========  ============================================  ==========================  =========

Instances (``config/clis.yaml``, Nav2-style): ``modules`` lists the instance names, and each
instance has a section with ``plugin: <entry-point name>`` (default: the section's name) and
that plug-in's parameters; two instances of one plug-in may differ (in their period, say). A
plug-in with ``defaults`` needs no section.

Speed limit (docs/design.md §3): a module deciding every ``tau_i`` may drive at most
``v_max,i = min(v_wheel_max, d_react / tau_i)``, so it moves at most ``d_react`` between two
decisions. Policy means are ``v_max,i W b`` (W dimensionless); the runner clamps the executed
command to ``v_max,i``; densities are of the proposed (pre-clamp) action.

Discount (11): ``gamma_i = gamma^(tau_i / base_tick)``. The paper prints ``gamma^{tau_i'}``;
we read the exponent as the number of base ticks in a module's period (docs/design.md §2), so one
second is discounted alike by every module and all optimise the same objective.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from clis_modules.core.module_params import (  # noqa: F401 - one import for the modules' users
    CONDITIONS,
    CommonParams,
    ModuleParamsLike,
    ModuleSetParams,
    PolicyParams,
    ValueParams,
    condition_periods,
    condition_sensors,
    instance_defaults,
    load_module_params,
    merge_section,
    module_gamma,
    speed_limit,
)
from clis_modules.core.plugin import (
    FeatureModel,
    Floor,
    ModuleContext,
    ModulePlugin,
    Percept,
)
from clis_modules.core.policy import GaussianPolicy
from clis_modules.core.value import LinearValue

__all__ = [
    'CONDITIONS', 'CommonParams', 'ValueParams', 'PolicyParams',
    'ModuleSetParams', 'load_module_params', 'instance_defaults', 'merge_section',
    'ModuleCore', 'build_module',
    'speed_limit', 'module_gamma', 'condition_periods', 'condition_sensors', 'make_modules',
    'make_module', 'arena_map',
]

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
        ``feature_fn(percept) -> b`` of shape (n,)
        (:class:`~clis_modules.core.plugin.Percept`).
    policy : GaussianPolicy
    value : LinearValue
    value_params : ValueParams
    policy_params : PolicyParams, optional
        ``None`` for a fixed policy (``learned`` is False).
    model : FeatureModel, optional
        The plug-in's model, for its hooks (:mod:`clis_modules.core.plugin`); None: no
        hooks.
    plugin : str
        The plug-in's name.
    sensors : tuple of str
        What the module reads (the plug-in's ``sensors``).

    Attributes
    ----------
    learned : bool
        Whether the policy is learned by (9) (view, place) or fixed (innate).
    model : FeatureModel or None
    on_motion, on_sense, peek_fn, at_pose, display : callable or None
        The model's hooks ``motion``, ``sense``, ``peek``, ``at_pose`` and ``display`` where
        it overrides them (:meth:`FeatureModel.has`), else None.
    state : object
        The model's state (the place module's ``MarkovLocalizer``), for inspection.
    visits : np.ndarray or None
        Selection counts ``C_i`` of the exploration bonus, shape (n,)
        (:func:`clis_modules.core.arbiter.uncertainty`; the learner adds to them after each
        learning episode); None without the bonus (``arbiter.bonus = 0``).
    """

    def __init__(self, name: str, period: float, gamma: float, v_max: float, n: int,
                 feature_fn: Any, policy: GaussianPolicy, value: LinearValue,
                 value_params: ValueParams, policy_params: PolicyParams | None = None,
                 model: FeatureModel | None = None, plugin: str = '',
                 sensors: tuple[str, ...] = ()) -> None:
        self.name = name
        self.plugin = plugin or name
        self.sensors = tuple(sensors)
        self.period = float(period)
        self.gamma = float(gamma)
        self.v_max = float(v_max)
        self.n = int(n)
        self.feature_fn = feature_fn
        self.policy = policy
        self.value_fn = value
        self.value_params = value_params
        self.policy_params = policy_params
        self.learned = policy_params is not None
        self.model = model

        def hook(name: str) -> Any:
            return getattr(model, name) if model is not None and model.has(name) else None
        self._reset = hook('reset')
        self.on_motion = hook('motion')
        self.on_sense = hook('sense')
        self.peek_fn = hook('peek')
        self.at_pose = hook('at_pose')
        self.display = hook('display')
        self.state = None if model is None else model.state
        self.visits: np.ndarray | None = None

    def __repr__(self) -> str:
        return (f'ModuleCore({self.name!r}, plugin={self.plugin!r}, period={self.period}, '
                f'gamma={self.gamma:.6f}, v_max={self.v_max:.4f}, n={self.n}, '
                f'learned={self.learned})')

    @property
    def localizer(self) -> Any:
        """The module's own state (:attr:`state`; the place module's ``MarkovLocalizer``)."""
        return self.state

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
        """Episode start: the plug-in's ``reset`` hook (the place module forgets its pose)."""
        if self._reset is not None:
            self._reset()

    def features(self, percept: Percept | float | None = None, d_o: float = math.nan,
                 landmark_bearings: ArrayLike | None = None) -> np.ndarray:
        """Features ``b_i(x)`` of the current observation, shape (n,) (a fresh array).

        Parameters
        ----------
        percept : Percept or float
            What the module reads (:class:`~clis_modules.core.plugin.Percept`); or, as a
            shorthand, the destination's bearing [rad] (NaN = not seen), with ``d_o`` [m] and
            ``landmark_bearings`` (M,) the other fields. A module with a state of its own
            (the place module) reads that state, which the decider updates first (its
            ``motion`` and ``sense`` hooks).
        """
        if not isinstance(percept, Percept):
            percept = Percept(math.nan, math.nan if percept is None else float(percept),
                              d_o, landmark_bearings)
        return self.feature_fn(percept)

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

def build_module(name: str, plugin: ModulePlugin, prm: Any, common: CommonParams,
                 period: float | None, landmarks_xy: ArrayLike, floor: Floor | float,
                 boxes: ArrayLike | None = None) -> ModuleCore:
    """Module instance ``name`` of ``plugin`` with parameters ``prm`` and period ``period``
    (default ``prm.period``): the plug-in's features and hooks, with the framework's value
    (1)(2), Gaussian policy (10), discount (11) and speed limit (docs/design.md §3)."""
    tau = float(prm.period if period is None else period)
    v_max = speed_limit(common, tau)
    if not isinstance(floor, Floor):
        floor = Floor.square(floor)
    ctx = ModuleContext(name, tau, v_max, common,
                        np.asarray(landmarks_xy, dtype=np.float64), floor,
                        None if boxes is None else np.asarray(boxes, dtype=np.float64))
    fm = plugin.model(prm, ctx)
    if not isinstance(fm, FeatureModel):
        raise TypeError(f'module plug-in {plugin.name!r}: model() must return a FeatureModel, '
                        f'got {type(fm).__name__}')
    n = int(fm.n)
    W = np.zeros((2, n)) if fm.W is None else np.asarray(fm.W, dtype=np.float64)  # noqa: N806
    learned = bool(plugin.learned)
    sigma = fm.sigma if fm.sigma is not None else prm.policy.sigma
    return ModuleCore(
        name, tau, module_gamma(common, tau), v_max, n, fm.features,
        GaussianPolicy(W, sigma, v_max, sigma_blind=fm.sigma_blind),
        LinearValue(n, prm.value.v_init), prm.value, prm.policy if learned else None,
        model=fm, plugin=plugin.name, sensors=plugin.sensors)


def arena_map(arena: Any) -> tuple[np.ndarray, Floor, np.ndarray]:
    """What the modules know of an arena (``cr_sim.core.arena.Arena``): landmark positions
    (M, 2), the floor, obstacle boxes (K, 4)."""
    landmarks = np.array([(lm.x, lm.y) for lm in arena.landmarks], dtype=np.float64)
    return landmarks, Floor.of(arena), np.array(arena.box_tuples(), dtype=np.float64)


def make_modules(params: ModuleParamsLike, condition: str, landmarks_xy: ArrayLike,
                 floor: Floor | float, boxes: ArrayLike | None = None) -> list[ModuleCore]:
    """The modules of one condition (paper Sec. IV, docs/design.md §3).

    Parameters
    ----------
    params : ClisParams
        Needs the section ``common`` and the instances of the condition.
    condition : str
        ``TIMING:MODULE+MODULE...`` or a paper name: ``'innate'``, ``'view'``, ``'place'``
        (that module alone, own period), ``'sync'`` (all three on the slowest period, with
        that period's speed limit and gamma), ``'async'`` (all three, own periods).
    landmarks_xy : array_like, shape (M, 2)
        Landmark positions [m], in the order of the observed bearings.
    floor : Floor or float
        The floor (:func:`arena_map`), or the half side [m] of a square one centred at the
        origin (:meth:`Floor.square`).
    boxes : array_like, shape (K, 4), optional
        Obstacles ``(xmin, ymin, xmax, ymax)`` [m] (the place module's grid excludes them).

    Returns
    -------
    list of ModuleCore
        In the condition's order.
    """
    return [make_module(params, name, period, landmarks_xy, floor, boxes)
            for name, period in condition_periods(params, condition)]


def make_module(params: ModuleParamsLike, name: str, period: float, landmarks_xy: ArrayLike,
                floor: Floor | float, boxes: ArrayLike | None = None) -> ModuleCore:
    """Module instance ``name``, with decision period ``period`` (:func:`condition_periods`);
    the other arguments as for :func:`make_modules`."""
    plugin, prm = params.module(name)
    return build_module(name, plugin, prm, params.common, period, landmarks_xy, floor, boxes)
