"""Cooperative learning: every module learns from every episode (paper II-B..E).

:meth:`Learner.learn` replays one :class:`~clis_learner.core.memory.EpisodeMemory` for each
module i (the *target*), whichever module acted (the *behaviour* i'):

1. module i's grid: its own decision times ``t_l`` and features ``b_i(x_l)``;
2. the executed actions resampled onto that grid, ``u_l`` (cubic spline or zero-order hold,
   :mod:`~clis_learner.core.resample`); rewards summed per interval ``[t_l, t_{l+1})``;
3. the ratio (7) ``rho_l = (pi_i(x_l, u_l) + eps) / (pi_i'(x'_l, u_l) + eps)``, where ``i'`` is
   the module whose command was in force at ``t_l`` and ``x'_l`` its state at ``t_l``:
   both densities at the same resampled data point ``(x(l tau_i), u(l tau_i))`` of (6)
   (``learner.behaviour_state = resampled``, the paper; the behaviour's features at ``t_l``
   come from its decision or its observation at that instant, :meth:`EpisodeMemory.states`),
   or its state at its latest decision ``<= t_l`` (``held``, the project's rule before the
   paper preset was made literal); ``rho_l = 1`` exactly (no density evaluated) when
   ``i' = i``;
4. TD(lambda) with IS (8) on ``w_i`` for every module (innate too);
5. the policy gradient with IS (9) on ``W_i`` (and ``sigma_i`` if ``learn_sigma``) for the
   learned modules.

Beyond the paper (``clis.yaml`` section ``learner``, :mod:`~clis_learner.core.updates`,
:mod:`~clis_learner.core.corrections`): ``behaviour = mixture`` replaces ``pi_i'`` of step 3 by
the selection mixture ``sum_j Pr(j | x) pi_j`` on every step (on-policy steps too);
``value_update = retrace`` replaces (8) in step 4 and ``policy_update = offpac`` replaces (9)
in step 5 by per-decision truncated corrections; ``step_norm = features`` divides the step
sizes of both by the feature mass ``b . b`` (``bounded``: and bounds each value step so
that no value of the episode's states moves by more than alpha times the TD error, Dabney &
Barto 2012, :func:`~clis_learner.core.updates.bounded_step`); ``imitation > 0`` adds
behaviour cloning of the executed actions where their return beat V_i (CRAIL; self-imitation)
to step 5;
``max_mean_step > 0`` bounds the change of the policy mean at the episode's states (a trust
region); with ``arbiter.bonus > 0`` the selection probabilities of the mixture include the
exploration bonus the episode was drawn with (:mod:`clis_modules.core.arbiter`), and after
the updates the acting module's selection counts take in its start features.

All densities of step 3 use the parameters the episode was played with: every ratio is computed
before any module is updated, so the order of the modules does not matter. The result depends
only on the memory and the parameters (no randomness).

Policy step (``learner.policy_step``, :func:`~clis_learner.core.updates.policy_step_scale`):
``paper`` (default) applies (9) to the gradient of (10) with its mean ``W_i b`` in m/s;
``dimensionless`` to the gradient with respect to the stored ``W`` of ``mean = v_max W b``
(v_max^2 times the paper's step); ``scaled`` multiplies the W gradient by ``sigma^2 / v_max^2``
and the sigma gradient by ``sigma^2 / (2 d)``, the inverse Fisher information of the Gaussian
(10) (beyond the paper: alpha is then a step in units of the speed limit).

Diagnostics (one dict per module, all floats, see :data:`DIAGNOSTIC_KEYS`):

==============  ==========================================================================
n_steps         L, decisions of the module in the episode
on_policy       share of steps where the module itself acted
rho_mean        mean of rho_l
c_final         c after the last step (importance product of the whole episode); with
                retrace: the importance weight min(rho_bar, rho_l) of the last step's TD error
c_min, c_median min and median of c_l over the steps (retrace: of the per-step weights)
c_max           max of c_l over the steps (how far the product of (8) grew)
grow_share      share of the steps with gamma_i rho_l > 1, where the trace of (8),
                e <- lambda gamma_i rho e + c b, and the product c grow
ess             (sum_l c_l)^2 / sum_l c_l^2, effective sample size of the steps' weights
v_start         V_i(x_0) before the update
v_abs_max       max_l |V_i(x_l)| over the episode's states before the update (the divergence
                guard, :mod:`~clis_learner.core.guard`)
ret             sum_l gamma_i^l r_l, the discounted return on module i's grid
delta_abs_mean  mean |delta_l| of (8)
grad_norm       Frobenius norm of the applied W direction, sum_k G_k dln pi_k/dW (0 if fixed)
sigma           sigma_i after the update
diverged        1 if the update produced non-finite parameters (then it is not applied)
==============  ==========================================================================
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import math

from clis_modules.core.arbiter import count_start, selection_probs, uncertainty
from clis_modules.core.modules import ModuleCore
import numpy as np

from clis_learner.core.config import ClisParams
from clis_learner.core.corrections import make_correction, mixture_density
from clis_learner.core.memory import EpisodeMemory
from clis_learner.core.resample import ActionTrack, latest_index, sum_rewards
from clis_learner.core.updates import (
    MASS_MIN,
    imitation_weights,
    offpac_weights,
    pg_weights,
    policy_step_scale,
    step_sizes,
    td_lambda_is,
    td_retrace,
)

__all__ = ['DIAGNOSTIC_KEYS', 'Replay', 'Learner']

#: Keys of each module's diagnostics, in a stable order (CSV columns).
DIAGNOSTIC_KEYS = ('n_steps', 'on_policy', 'rho_mean', 'grow_share', 'c_final', 'c_min',
                   'c_median', 'c_max', 'ess',
                   'v_start', 'v_abs_max', 'ret', 'delta_abs_mean', 'grad_norm', 'sigma',
                   'diverged')


@dataclass(frozen=True)
class Replay:
    """Module i's view of one episode (steps 1-3 of the module docstring).

    Attributes
    ----------
    t : np.ndarray, shape (L,)
        Module i's decision times [s].
    B : np.ndarray, shape (L, n)
        Its features ``b_i(x_l)``.
    U : np.ndarray, shape (L, 2)
        The executed actions resampled at ``t`` [m/s].
    rho : np.ndarray, shape (L,)
        Ratios (7); exactly 1 where ``on``.
    r : np.ndarray, shape (L,)
        Rewards summed over ``[t_l, t_{l+1})`` (the last interval up to the end).
    on : np.ndarray of bool, shape (L,)
        Whether module i itself was acting at ``t_l``.
    """

    t: np.ndarray
    B: np.ndarray
    U: np.ndarray
    rho: np.ndarray
    r: np.ndarray
    on: np.ndarray


class Learner:
    """Learns every module from one episode (module docstring).

    Parameters
    ----------
    modules : sequence of ModuleCore
        The modules of the condition (updated in place by :meth:`learn`).
    params : ClisParams
        Reads ``learner`` and ``common.epsilon``.
    """

    def __init__(self, modules: Sequence[ModuleCore], params: ClisParams) -> None:
        self.modules = list(modules)
        self.by_name = {m.name: m for m in self.modules}
        self.params = params.learner
        self.arbiter = params.arbiter
        self.beta = params.common.beta
        self.correction = make_correction(self.params.correction, params.common.epsilon)
        self.resampled = self.params.behaviour_state == 'resampled'
        #: Off-policy steps whose behaviour density was scored at a held state (its latest
        #: decision) since the learner was made: with ``behaviour_state = resampled``, the
        #: off-policy steps scored at a held state for want of an observation (resampled).
        self.held_steps = 0

    def learn(self, memory: EpisodeMemory, update: bool = True) -> dict[str, dict[str, float]]:
        """Replay one ended episode for every module; apply (8) and (9) unless ``update`` is
        False (evaluation: diagnostics only).

        Returns
        -------
        dict
            ``{module name: {key: float}}`` with the keys of :data:`DIAGNOSTIC_KEYS`.
        """
        if not memory.ended:
            raise RuntimeError('learn() needs an ended episode: call memory.end() first')
        t_a, u_a, _ = memory.actions()
        track = ActionTrack(t_a, u_a, self.params.resample) if len(t_a) else None
        # a learning episode was drawn with the exploration bonus (Selector.explore_now)
        kappa = self.arbiter.bonus if update else 0.0
        # before any update
        replays = {m.name: self.replay(m, memory, track, kappa) for m in self.modules}
        # Diverging weights (the paper preset's TD(lambda) with (7): docs/results.md) overflow
        # to inf/NaN: that is detected and reported per module ('diverged', the update is then
        # not applied), so numpy's warnings would only flood a long run's output
        with np.errstate(over='ignore', invalid='ignore'):
            out = {m.name: self._learn_module(m, replays[m.name], update)
                   for m in self.modules}
        if update:
            for m in self.modules:
                rp = replays[m.name]
                if m.visits is not None and rp is not None and rp.on[0]:
                    # the acting module was chosen from x_0: C_i += |b_i(x_0)| / sum |b_i(x_0)|
                    m.visits = count_start(m.visits, rp.B[0])
        return out

    # ------------------------------------------------------------------ step 1-3

    def replay(self, m: ModuleCore, memory: EpisodeMemory,
               track: ActionTrack | None = None, kappa: float | None = None) -> Replay | None:
        """Module ``m``'s view of the episode with the current parameters (``None`` if it never
        decided before the end or nothing was executed). ``track``: the episode's executed
        actions (:class:`ActionTrack` of ``memory.actions()``, shared by the modules' replays;
        made here by default); ``kappa``: the exploration bonus the episode was drawn with
        (default ``arbiter.bonus``)."""
        t_i, B = memory.decisions(m.name)  # noqa: N806
        t_a, u_a, who_a = memory.actions()
        if B is None or len(t_a) == 0:
            return None
        if track is None:
            track = ActionTrack(t_a, u_a, self.params.resample)
        U = track.at(t_i)  # noqa: N806
        beh = who_a[latest_index(t_a, t_i)]                 # behaviour i' at each t_l
        on = beh == memory.index(m.name)
        rho = np.ones(len(t_i))
        off = ~on
        r = sum_rewards(*memory.rewards(), t_i)
        if self.params.behaviour == 'mixture':
            pi, probs = self.mixture_terms(memory, t_i, U, kappa)
            # balance heuristic: rho = pi_i / sum_j Pr(j|x) pi_j on every step (on-policy too)
            rho = self.correction.ratio(pi[:, self.modules.index(m)],
                                        mixture_density(pi, probs))
            return Replay(t_i, B, U, rho, r, on)
        if off.any():
            pi_target = m.policy.density_batch(B[off], U[off])
            pi_behaviour = np.empty(int(off.sum()))
            for j in np.unique(beh[off]):
                name = memory.module_names[j]
                if name not in self.by_name:
                    raise KeyError(f"behaviour module {name!r} is not one of the learner's")
                sel = beh[off] == j
                # (6) pi_i'(x(l tau_i), u(l tau_i)): the behaviour's state at the target's
                # instant (resampled), or at its latest decision <= l tau_i (held)
                B_j, exact = memory.states(name, t_i[off][sel], self.resampled)  # noqa: N806
                self.held_steps += int(np.count_nonzero(~exact))
                pi_behaviour[sel] = self.by_name[name].policy.density_batch(
                    B_j, U[off][sel])
            # (7) rho~ = (pi_i + eps) / (pi_i' + eps); rho = 1 exactly where i' = i
            rho[off] = self.correction.ratio(pi_target, pi_behaviour)
        return Replay(t_i, B, U, rho, r, on)

    def mixture_terms(self, memory: EpisodeMemory, t: np.ndarray, U: np.ndarray,  # noqa: N803
                      kappa: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Densities of every module and the selection probabilities on a grid ``t``.

        Module j's density ``pi_j(x_j, u_l)`` is at its latest decision ``<= t_l``; the
        probabilities are those of the arbiter's rule (3): at the start state for
        ``arbiter.selection = episode`` (one draw per episode), at each step's latest values
        for ``decision``; with ``kappa > 0`` (default ``arbiter.bonus``) including the
        exploration bonus ``kappa u_j(x_0)`` of the start state.

        The values are those the modules proposed with (:meth:`EpisodeMemory.values`), the
        numbers the arbiter drew from, so the probabilities are the drawn ones bit for bit on
        any CPU (a matrix-vector product ``B_j w_j`` over the decisions may round differently
        from the modules' one dot product per decision, by BLAS kernel); a decision recorded
        without its value gets it from :meth:`ModuleCore.value`, the modules' own code.

        Returns
        -------
        pi : np.ndarray, shape (L, N)
        probs : np.ndarray, shape (L, N) or (N,)
        """
        kappa = self.arbiter.bonus if kappa is None else kappa
        pi = np.empty((len(t), len(self.modules)))
        values = np.empty((len(t), len(self.modules)))
        bonus = np.zeros(len(self.modules)) if kappa > 0.0 else None
        for j, mod in enumerate(self.modules):
            t_j, B_j = memory.decisions(mod.name)  # noqa: N806
            if B_j is None:
                raise ValueError(f'module {mod.name!r} never recorded a decision')
            k = latest_index(t_j, t)
            pi[:, j] = mod.policy.density_batch(B_j[k], U)
            v_j = memory.values(mod.name)
            if np.isnan(v_j).any():
                # (1)(2) V_j = w_j^T b_j, one decision at a time as the module computes it
                v_j = np.array([mod.value(b) for b in B_j])
            values[:, j] = v_j[k]
            if bonus is not None and mod.visits is not None:
                # the bonus kappa u_j(x_0) of the episode's draw (selection = episode), from
                # the counts the episode was played with (updated after learn())
                bonus[j] = kappa * uncertainty(B_j[k[0]], mod.visits)
        gammas = [mod.gamma for mod in self.modules]
        rows = values[:1] if self.arbiter.selection == 'episode' else values
        probs = np.array([selection_probs(v, gammas, self.beta, None, self.arbiter.rule,
                                          self.arbiter.scale_min, self.arbiter.explore, bonus)
                          for v in rows])
        return pi, probs[0] if self.arbiter.selection == 'episode' else probs

    # ------------------------------------------------------------------ step 4-5

    def _learn_module(self, m: ModuleCore, rp: Replay | None,
                      update: bool) -> dict[str, float]:
        if rp is None:
            out = dict.fromkeys(DIAGNOSTIC_KEYS, math.nan)
            out.update(n_steps=0.0, grad_norm=0.0, sigma=m.sigma, diverged=0.0)
            return out
        n_steps = len(rp.r)
        v_start = m.value(rp.B[0])
        prm = self.params
        v_before = rp.B @ m.w
        alpha = (m.value_params.alpha if prm.step_norm == 'none'
                 else step_sizes(m.value_params.alpha, rp.B, prm.step_norm))
        # bounded: no value of the episode's states moves by more than alpha |delta| per step
        # (updates.bounded_step: Dabney & Barto 2012's bound over the episode's states)
        cap = m.value_params.alpha if prm.step_norm == 'bounded' else None
        if prm.value_update == 'retrace':
            # Retrace(lambda) / V-trace: per-decision truncated weights (updates.td_retrace)
            w_new, delta, c = td_retrace(m.w, rp.B, rp.r, rp.rho, m.gamma, prm.lambda_,
                                         alpha, prm.rho_bar, cap)
        else:
            # (8) TD(lambda) with importance sampling
            w_new, delta, c = td_lambda_is(m.w, rp.B, rp.r, rp.rho, m.gamma, prm.lambda_,
                                           alpha, cap)
        grad_norm = 0.0
        W_new, sigma_new = m.W, m.sigma  # noqa: N806
        if m.learned:
            pp = m.policy_params
            if prm.policy_update == 'offpac':
                # Off-PAC / V-trace actor: min(rho_bar, rho_l) A_l d ln pi, V_i the baseline
                g = offpac_weights(v_before, rp.r, rp.rho, m.gamma, prm.lambda_, prm.rho_bar)
            else:
                # (9) sum over the episode of gamma_i^t r c e, e = accumulated d ln pi / d W
                g = pg_weights(rp.r, c, m.gamma)
            if prm.imitation > 0.0:
                # CRAIL / self-imitation: clone u_l where G_l beat V_i(x_l) (updates module)
                g = g + imitation_weights(v_before, rp.r, m.gamma, prm.imitation)
            if prm.step_norm != 'none':
                g = g / np.maximum(np.einsum('ln,ln->l', rp.B, rp.B), MASS_MIN)
            d_w, d_sigma = m.policy.weighted_scores(rp.B, rp.U, g)
            # (9) on (10): the step in the units of learner.policy_step (updates module)
            f_w, f_sigma = policy_step_scale(self.params.policy_step, m.v_max, m.sigma)
            d_w *= f_w
            d_sigma *= f_sigma
            if prm.max_mean_step > 0.0:
                # trust region (cf. TRPO, Schulman et al. 2015): the episode's summed update may
                # move the mean v_max W b at any of its states by at most max_mean_step sigma
                # (KL <= max_mean_step^2 / 2 per state); a long episode stuck in one state no
                # longer adds up to a step many times the error
                shift = m.v_max * pp.alpha * np.linalg.norm(rp.B @ d_w.T, axis=1).max()
                limit = prm.max_mean_step * m.sigma
                if shift > limit:
                    d_w = d_w * (limit / shift)
            grad_norm = float(np.linalg.norm(d_w))
            # (9) W_i <- W_i + alpha_i gamma_i^t r c_i e_i
            W_new = m.W + pp.alpha * d_w  # noqa: N806
            if pp.learn_sigma:
                sigma_new = min(max(m.sigma + pp.alpha_sigma * d_sigma, pp.sigma_min),
                                pp.sigma_max)
        diverged = not (np.all(np.isfinite(w_new)) and np.all(np.isfinite(W_new))
                        and math.isfinite(sigma_new))
        if update and not diverged:
            m.w = w_new
            if m.learned:
                m.W = W_new
                m.sigma = sigma_new
        with np.errstate(over='ignore', invalid='ignore'):
            s1, s2 = float(c.sum()), float(np.sum(c * c))
            ess = s1 * s1 / s2 if s2 > 0.0 and math.isfinite(s1 * s1 / s2) else 0.0
        return {
            'n_steps': float(n_steps),
            'on_policy': float(np.mean(rp.on)),
            'rho_mean': float(np.mean(rp.rho)),
            'grow_share': float(np.mean(m.gamma * rp.rho > 1.0)),
            'c_final': float(c[-1]),
            'c_min': float(c.min()),
            'c_median': float(np.median(c)),
            'c_max': float(c.max()),
            'ess': ess,
            'v_start': v_start,
            'v_abs_max': float(np.max(np.abs(v_before))),
            'ret': float(np.sum(m.gamma ** np.arange(n_steps) * rp.r)),
            'delta_abs_mean': float(np.mean(np.abs(delta))),
            'grad_norm': grad_norm,
            'sigma': m.sigma,
            'diverged': float(diverged),
        }

