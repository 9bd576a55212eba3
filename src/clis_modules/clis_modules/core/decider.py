"""One module deciding at its period: sensors -> features -> proposal (paper II-E, Fig. 1).

"Each module determines action *asynchronously*" (paper II-E): at each of its decision times
``t_l = t_0 + l tau_i`` module i reads the robot's sensors of that instant, forms its state
``x(t_l)`` and features ``b_i(x)``, and proposes an action ``u ~ pi_i(x, .)`` (10) together with
its value ``V_i(x) = w_i^T b_i(x)`` (1)(2), by which the arbiter selects (3).

:class:`Decider` is that step, shared by the two schedulers of the project: the headless runner
(:mod:`clis_app.experiments.runner`, a discrete-event loop at the simulator tick) and the module
nodes (:mod:`clis_modules.module_node`, an rclpy timer of period ``tau_i``). It holds what a
module carries between decisions: for a module with a ``motion`` hook (the place module), the
odometry since its last decision, which that hook applies (the motion update of its Markov
localization) before the ``sense`` hook (the landmark update, paper III-D). Everything else is
in the :class:`~clis_modules.core.modules.ModuleCore` and its plug-in
(:mod:`clis_modules.core.plugin`).

Inputs are plain values (:class:`~clis_modules.core.plugin.Percept`, wheel velocities), so a
simulator observation or decoded ROS messages drive it alike.
"""

from __future__ import annotations

import copy
import math

from cr_sim.core.kernels import odometry, odometry_step
import numpy as np
from numpy.typing import ArrayLike

from clis_modules.core.arbiter import uncertainty
from clis_modules.core.modules import ModuleCore
from clis_modules.core.plugin import Percept
from clis_modules.core.policy import ACTION_DIM
from clis_modules.core.proposal import Proposal

__all__ = ['Percept', 'Decider']


class Decider:
    """Module i's decisions within one episode (module docstring).

    Parameters
    ----------
    module : ModuleCore
        The module (its parameters may be replaced between episodes).
    rng : np.random.Generator
        Draws the proposals (two standard normals per decision).
    wheel_base : float
        Distance between the wheels [m], to turn wheel velocities into odometry.
    """

    def __init__(self, module: ModuleCore, rng: np.random.Generator,
                 wheel_base: float) -> None:
        self.module = module
        self.rng = rng
        self.wheel_base = float(wheel_base)
        self.version = 0
        self.reset()

    @property
    def name(self) -> str:
        return self.module.name

    @property
    def tracks_motion(self) -> bool:
        """Whether the module integrates odometry (a ``motion`` hook: the place module)."""
        return self.module.on_motion is not None

    def reset(self) -> None:
        """Episode start: the module's ``reset`` hook (the place module forgets its pose,
        paper III-D)."""
        self.module.reset()
        self._odo = (0.0, 0.0, 0.0)
        self._first = True

    def on_wheels(self, v_left: float, v_right: float, dt: float) -> None:
        """The robot drove the wheel velocities ``(v_left, v_right)`` [m/s] for ``dt`` [s].

        A module with a ``motion`` hook composes them into one displacement in the robot frame
        at its last decision (odometry), for its next motion update; other modules ignore them.
        """
        if self.module.on_motion is None:
            return
        # wheels_to_twist then integrate_arc, compiled (called at every simulator tick)
        self._odo = odometry_step(*self._odo, v_left, v_right, self.wheel_base, dt)

    def on_wheel_steps(self, wheels: np.ndarray, dt: float) -> None:
        """:meth:`on_wheels` for each row ``(v_left, v_right)`` of ``wheels`` (K, 2), oldest
        first, each held for ``dt`` [s] (the steps of :meth:`cr_sim.core.sim.Simulator.hold`):
        the same arithmetic, compiled as one loop."""
        if self.module.on_motion is None:
            return
        self._odo = odometry(*self._odo, wheels, self.wheel_base, dt)

    def decide(self, percept: Percept) -> Proposal:
        """Decide at ``percept.t``: features, then ``u ~ pi_i(x, .)`` (10) and ``V_i(x)``."""
        m = self.module
        first = self._first
        if m.on_motion is not None and not first:
            # the place module, paper III-D: b(x') <- sum_x Pr(x' | x, u) b(x), u = odometry
            # since the last decision (none before the first decision of an episode)
            m.on_motion(*self._odo)
            self._odo = (0.0, 0.0, 0.0)
        if m.on_sense is not None:
            # the place module, paper III-D: b(x) <- eta Pr(s | x) b(x)
            m.on_sense(percept)
        self._first = False
        b = m.feature_fn(percept)
        pol = m.policy
        sigma = pol.sigma_at(b)
        # (10) mean v_max W_i b (GaussianPolicy.mean; b is a fresh float64 array already),
        # u ~ N(v_max W_i b, sigma_i^2 I): numpy's element-wise products and sums of the two
        # components, done on Python floats (the same IEEE operations, without four arrays)
        wb0, wb1 = (pol.W @ b).tolist()
        n0, n1 = self.rng.standard_normal(ACTION_DIM).tolist()
        v_max = pol.v_max
        m0, m1 = v_max * wb0, v_max * wb1
        # (1)(2) V_i(x) = w_i^T b_i(x) (LinearValue.__call__)
        value = float(m.value_fn.w @ b)
        return Proposal(m.name, float(percept.t), b,
                        np.array((m0 + sigma * n0, m1 + sigma * n1)), np.array((m0, m1)),
                        float(sigma), value, self.version,
                        # the exploration bonus's u_i(x_0): read at the episode's first draw
                        uncertainty(b, m.visits) if first and m.visits is not None else 0.0)

    def observe(self, percept: Percept) -> np.ndarray:
        """Features ``b_i(x(t))`` at ``percept.t``, an instant at which the module does not
        decide, without deciding: no draw, and its state is left as it is (a module with a
        ``peek`` hook gives the features its next ``motion`` and ``sense`` would give at ``t``:
        the place module's :meth:`MarkovLocalizer.peek`). The learner scores the module's
        density there when it is the behaviour of another module's decision (paper (6): both
        densities at ``x(l tau_i)``)."""
        m = self.module
        if m.peek_fn is None:
            return m.feature_fn(percept)
        return m.peek_fn(None if self._first else self._odo, percept)

    def warm_up(self, n_landmarks: int) -> None:
        """Run a copy of this decider through every path of an episode once, so that the
        compiled kernels it calls (numba, compiled lazily at their first call, or loaded from
        the on-disk cache) are ready before the first real decision; this decider, its module
        and its generator are left untouched.

        A module node calls it before it joins the graph: a kernel compiled at the first
        decision of a run takes seconds (a fresh clone has no cache), and a lockstep arbiter
        waiting for that decision would give up on it and answer without the module, so the
        run would no longer be the headless runner's (seen: every module missed t = 0 with a
        cold cache). ``n_landmarks``: the length of ``Percept.landmark_bearings``.
        """
        twin = copy.deepcopy(self)
        m = twin.module
        twin.set_parameters(m.w.copy(), m.W.copy(), float(m.sigma), self.version)
        seen = np.linspace(-1.0, 1.0, n_landmarks)
        partly = seen.copy()
        partly[::2] = math.nan
        for _ in range(2):                   # (the second episode: after a reset)
            twin.reset()
            for k, (dest, lm) in enumerate([(0.3, seen), (math.nan, partly),
                                             (-0.2, np.full(n_landmarks, math.nan))]):
                twin.on_wheels(0.1, 0.12, 0.05)
                twin.on_wheel_steps(np.array([[0.1, 0.12], [0.08, 0.1]]), 0.05)
                twin.decide(Percept(0.05 * k, dest, 0.4, lm, np.full(7, 0.4),
                                    np.array([0.1, 0.12])))

    def set_parameters(self, w: ArrayLike, W: ArrayLike, sigma: float,  # noqa: N803
                       version: int) -> None:
        """Replace the module's learned parameters (between episodes): value weights ``w``
        (n,), policy weights ``W`` (2, n), ``sigma``; validated before anything changes."""
        m = self.module
        w = np.asarray(w, dtype=np.float64)
        W = np.asarray(W, dtype=np.float64)  # noqa: N806
        if w.shape != (m.n,) or W.shape != (2, m.n):
            raise ValueError(f'{m.name}: parameters of shape w {w.shape}, W {W.shape} do not '
                             f'fit n = {m.n} features (same condition and config?)')
        if not (np.all(np.isfinite(w)) and np.all(np.isfinite(W)) and math.isfinite(sigma)
                and sigma > 0.0):
            raise ValueError(f'{m.name}: non-finite parameters or sigma <= 0')
        m.w = w
        if m.learned:
            m.W = W
            m.sigma = sigma
        self.version = int(version)
