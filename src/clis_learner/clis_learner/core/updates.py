"""The update rules of CLIS: TD(lambda) with importance sampling (8), policy gradient with
importance sampling (9), and the semi-MDP discount (11); beyond the paper, per-decision
truncated corrections (Retrace / V-trace for the values, an off-policy actor-critic for the
policies) and step sizes normalised by the feature mass.

Which rule (``learner.value_update``, ``learner.policy_update``):

========  ===============================================================================
paper     (8) and (9): every step weighted by the product ``c_l`` of all ratios so far
retrace   value: per-decision importance sampling (Precup et al. 2000) with traces cut at
          ``lambda min(c_bar, rho)`` (Retrace(lambda), Munos et al. 2016) and the TD error
          weighted by ``min(rho_bar, rho)`` (V-trace, Espeholt et al. 2018): no product over
          the episode, so an off-policy episode teaches every step where the target agrees
offpac    policy: ``min(rho_bar, rho_l) A_l d ln pi(x_l, u_l)`` per step with the advantage
          ``A_l = r_l + gamma_i v_{l+1} - V_i(x_l)`` against the module's own V_i (Off-PAC,
          Degris et al. 2012; the V-trace actor, Espeholt et al. 2018) instead of (9)'s
          return times the episode product and no baseline
========  ===============================================================================

Indexing (our reading of the paper's ``rho~_i(t + tau_i)``): module i's episode is the sequence
of its decision states ``x_0 .. x_{L-1}`` at times ``t_0 < .. < t_{L-1}``; step ``l`` is the
transition ``x_l -> x_{l+1}`` under the (resampled) action ``u_l = u(t_l)`` with the reward
``r_l`` summed over ``[t_l, t_{l+1})``. ``rho_l`` is the ratio of the action ``u_l`` that
generated step l (evaluated when the step completes, at ``t + tau_i``), so the product
``c_l = rho_0 ... rho_l`` weights the reward ``r_l`` by exactly the actions that preceded it.
The step after ``x_{L-1}`` ends the episode (goal or timeout): ``V(x_L) = 0`` (the time limit
is not part of any module's state, so a timeout is treated as terminal).
"""

from __future__ import annotations

from clis_modules.core.value import gamma_i
from cr_sim.core.kernels import njit
import numpy as np
from numpy.typing import ArrayLike

__all__ = ['POLICY_STEPS', 'policy_step_scale', 'C_MAX', 'gamma_i', 'importance_products',
           'td_lambda_is', 'pg_weights',
           'policy_gradient_is', 'VALUE_UPDATES', 'POLICY_UPDATES', 'STEP_NORMS',
           'step_sizes', 'td_retrace', 'vtrace_targets', 'offpac_weights',
           'discounted_returns', 'imitation_weights', 'bounded_step']

#: ``learner.value_update``, ``learner.policy_update``, ``learner.step_norm``.
VALUE_UPDATES = ('paper', 'retrace')
POLICY_UPDATES = ('paper', 'offpac')
STEP_NORMS = ('none', 'features', 'bounded')
#: ``learner.policy_step``: how the score of (10) is turned into the step of (9), see
#: :func:`policy_step_scale`.
POLICY_STEPS = ('paper', 'dimensionless', 'scaled')
#: Smallest feature mass ``b . b`` a normalised step divides by (a state with no feature on).
MASS_MIN = 1e-3

#: Upper clip of the importance product ``c`` (never reached in practice; keeps it finite).
C_MAX = 1e100


def importance_products(rho: ArrayLike) -> np.ndarray:
    """``c_l = prod_{k <= l} rho_k`` (the ``c_i <- rho~_i c_i`` of (8) and (9), ``c`` = 1 before
    the first step), clipped to ``[0, C_MAX]``.

    Parameters
    ----------
    rho : array_like, shape (L,)

    Returns
    -------
    np.ndarray, shape (L,)
    """
    # (8)(9) c_i <- rho~_i c_i, from c_i = 1 at the episode start
    with np.errstate(over='ignore'):
        return np.minimum(np.cumprod(np.asarray(rho, dtype=np.float64)), C_MAX)


def td_lambda_is(w: ArrayLike, B: ArrayLike, r: ArrayLike, rho: ArrayLike,  # noqa: N803
                 gamma_i: float, lambda_: float, alpha: float | ArrayLike,
                 cap: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """TD(lambda) with importance sampling over one episode, eq. (8), online.

    For ``l = 0 .. L-1`` (module docstring for the indexing)::

        c     <- rho_l c
        delta <- r_l + gamma_i c V(x_{l+1}) - V(x_l)          V(x_L) = 0 (episode end)
        e     <- lambda gamma_i rho_l e + c b(x_l)            e = 0 at the start
        w     <- w + alpha delta e

    with ``V(x) = w^T b(x)`` at the current ``w`` (online: each step sees the previous update).

    Parameters
    ----------
    w : array_like, shape (n,)
        Value weights before the episode (not modified).
    B : array_like, shape (L, n)
        Features ``b(x_l)``.
    r : array_like, shape (L,)
        Rewards ``r_l`` of each step.
    rho : array_like, shape (L,)
        Ratios ``rho~_l`` (7).
    gamma_i, lambda_ : float
        Discount per step (11), trace decay.
    alpha : float or array_like, shape (L,)
        Step size, or one per step (:func:`step_sizes`, beyond the paper).
    cap : float, optional
        Beyond the paper: bound every step so that no value of the episode's states moves by
        more than ``cap`` times the TD error (:func:`bounded_step`); None = the paper's.

    Returns
    -------
    w : np.ndarray, shape (n,)
        Weights after the episode.
    delta : np.ndarray, shape (L,)
        TD errors.
    c : np.ndarray, shape (L,)
        Importance products after each step.
    """
    w = np.array(w, dtype=np.float64)
    B = np.asarray(B, dtype=np.float64)  # noqa: N806
    rho = np.asarray(rho, dtype=np.float64)
    c = importance_products(rho)
    n_steps = B.shape[0]
    decay = lambda_ * gamma_i * rho
    alpha_l = np.ascontiguousarray(np.broadcast_to(np.asarray(alpha, dtype=np.float64),
                                                   (n_steps,)))
    delta = _td_lambda_is_steps(w, np.ascontiguousarray(B), np.asarray(r, dtype=np.float64),
                                c, decay, alpha_l, float(gamma_i),
                                0.0 if cap is None else float(cap))
    return w, delta, c


@njit
def _td_lambda_is_steps(w: np.ndarray, B: np.ndarray, r: np.ndarray,  # noqa: N803
                        c: np.ndarray, decay: np.ndarray, alpha: np.ndarray,
                        gamma_i: float, cap: float) -> np.ndarray:
    """The steps of :func:`td_lambda_is`, compiled: ``w`` updated in place, the TD errors
    returned. ``np.dot`` is the BLAS dot product numpy's ``@`` calls (same results, tested).
    ``cap > 0``: each step bounded by :func:`bounded_step` (0: the paper's step)."""
    n_steps, n = B.shape
    e = np.zeros(n)
    delta = np.empty(n_steps)
    for l in range(n_steps):  # noqa: E741 - the paper's step index
        v = np.dot(w, B[l])
        v_next = np.dot(w, B[l + 1]) if l + 1 < n_steps else 0.0
        # (8) delta_i <- r + gamma_i c_i V_i(x') - V_i(x)
        d = r[l] + gamma_i * c[l] * v_next - v
        # (8) e_i <- lambda_i gamma_i rho~_i e_i + c_i b_i(x)
        # (8) w_i <- w_i + alpha_i delta_i e_i
        if cap > 0.0:
            for j in range(n):
                e[j] = e[j] * decay[l] + c[l] * B[l, j]
            # bounded: no value of the episode's states moves by more than cap |delta|
            step = bounded_step(alpha[l], cap, B, e) * d
            for j in range(n):
                w[j] += step * e[j]
        else:
            step = alpha[l] * d
            for j in range(n):
                e[j] = e[j] * decay[l] + c[l] * B[l, j]
                w[j] += step * e[j]
        delta[l] = d
    return delta


def pg_weights(r: ArrayLike, c: ArrayLike, gamma_i: float) -> np.ndarray:
    """Weight of each step's score in the policy gradient of one episode, eq. (9).

    (9) adds ``alpha gamma_i^l r_l c_l e_l`` at every step, with the trace
    ``e_l = sum_{k <= l} d ln pi(x_k, u_k) / dW``. The scores are evaluated at the policy of the
    episode (it is not updated while the episode is replayed), so the sum of the updates is
    ``alpha sum_k G_k d ln pi(x_k, u_k) / dW`` with the reverse cumulative sum::

        G_k = sum_{l >= k} gamma_i^l r_l c_l

    Parameters
    ----------
    r, c : array_like, shape (L,)
        Rewards and importance products of each step.
    gamma_i : float

    Returns
    -------
    np.ndarray, shape (L,)
    """
    r = np.asarray(r, dtype=np.float64)
    # (9) per-step factor gamma_i^t r(t + tau_i) c_i, t = step index on module i's grid
    x = gamma_i ** np.arange(len(r)) * r * np.asarray(c, dtype=np.float64)
    return np.cumsum(x[::-1])[::-1]


def policy_gradient_is(scores: ArrayLike, r: ArrayLike, rho: ArrayLike, gamma_i: float,
                       alpha: float) -> np.ndarray:
    """Total change of the policy parameters over one episode by (9).

    ::

        c <- rho_l c;   e <- e + d ln pi(x_l, u_l) / dW;   W <- W + alpha gamma_i^l r_l c e

    Parameters
    ----------
    scores : array_like, shape (L, P)
        ``d ln pi(x_l, u_l) / d theta`` of each step (flattened parameters).
    r, rho : array_like, shape (L,)
    gamma_i, alpha : float

    Returns
    -------
    np.ndarray, shape (P,)
        ``alpha sum_k G_k scores_k`` (:func:`pg_weights`).
    """
    g = pg_weights(r, importance_products(rho), gamma_i)
    return alpha * (g @ np.asarray(scores, dtype=np.float64))


def step_sizes(alpha: float, B: ArrayLike, norm: str) -> np.ndarray:  # noqa: N803
    """Step size of each step: ``alpha`` (``none``), or ``alpha / (b_l . b_l)`` (``features``,
    and ``bounded`` before :func:`bounded_step`).

    Normalised LMS: with ``alpha / (b . b)`` a step ``w <- w + alpha delta b / (b . b)`` moves
    ``V(x_l) = w . b_l`` by exactly ``alpha delta``, whether the features are a concentrated
    belief (``b . b`` ~ 1) or spread RBFs (``b . b`` ~ 0.1): the place module's diffuse early
    beliefs no longer learn 100x slower than its localized ones.

    Parameters
    ----------
    alpha : float
    B : array_like, shape (L, n)
    norm : str
        ``none``, ``features`` or ``bounded``.

    Returns
    -------
    np.ndarray, shape (L,)
    """
    B = np.asarray(B, dtype=np.float64)  # noqa: N806
    if norm == 'none':
        return np.full(B.shape[0], float(alpha))
    if norm not in STEP_NORMS:
        raise ValueError(f'unknown step_norm {norm!r}: choose from {", ".join(STEP_NORMS)}')
    return alpha / np.maximum(np.einsum('ln,ln->l', B, B), MASS_MIN)


@njit
def bounded_step(alpha_l: float, cap: float, B: np.ndarray, e: np.ndarray) -> float:  # noqa: N803
    """The step of a TD update along the trace ``e``, bounded so that the value of no state of
    the episode moves by more than ``cap`` times the TD error (``step_norm = bounded``).

    ``w <- w + a delta e`` moves ``V(x_k) = w . b_k`` by ``a delta (e . b_k)``. With the
    normalised step ``a = alpha / (b_l . b_l)`` alone (normalised LMS) and a trace, that is up
    to ``alpha delta (e . b_k) / (b_l . b_l)``: many times ``alpha delta`` when the trace holds
    states of larger feature mass than ``x_l`` (a robot that saw the goal for a while, then a
    spread RBF state: ``b . b`` 1 against 0.1), which overshoots the TD error and diverges
    (View alone under the improved preset without it: |V| up to 1e12). Hence::

        a = min(alpha_l, cap / max_k |e . b_k|)        k over the episode's states

    so ``|Delta V(x_k)| <= cap |delta|`` at every visited state, the current one included. It
    is the overshoot bound of Dabney & Barto (2012, "Adaptive step-size for online temporal
    difference learning": ``a <= 1 / |e . (gamma b' - b)|``, no reversal of the current TD
    error) taken over every state of the episode rather than the current transition, with
    ``cap = alpha`` the normalised-LMS move; without a trace (``e = b_l``) and with
    ``b_l . b_l >= b_k . b_l`` it is ``alpha_l`` unchanged.

    Parameters
    ----------
    alpha_l : float
        The unbounded step of this step (:func:`step_sizes`).
    cap : float
        Largest move of a value per unit TD error (``alpha``).
    B : np.ndarray, shape (L, n)
        Features of the episode's states (C-contiguous float64: compiled).
    e : np.ndarray, shape (n,)
        The trace after this step's features were added.

    Returns
    -------
    float
    """
    # Dabney & Barto 2012 bound over the episode's states: max_k |a e . b_k| <= cap
    move = np.abs(np.dot(B, e)).max()
    return min(alpha_l, cap / max(move, MASS_MIN))


def td_retrace(w: ArrayLike, B: ArrayLike, r: ArrayLike, rho: ArrayLike,  # noqa: N803
               gamma_i: float, lambda_: float, alpha: ArrayLike, rho_bar: float = 1.0,
               cap: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """TD(lambda) with per-decision truncated importance weights, online (beyond the paper).

    Retrace(lambda) (Munos et al. 2016) for a state value, in the form of V-trace (Espeholt
    et al. 2018)::

        delta <- r_l + gamma_i V(x_{l+1}) - V(x_l)                 V(x_L) = 0
        e     <- gamma_i lambda min(rho_bar, rho_{l-1}) e + b(x_l)  e = 0 at the start
        w     <- w + alpha_l min(rho_bar, rho_l) delta e

    Offline (fixed w) the summed update is ``sum_l (v_l - V(x_l)) b(x_l)`` with the V-trace
    target ``v_l`` (:func:`vtrace_targets`, ``c_bar = lambda rho_bar``). Unlike (8), no product
    of ratios multiplies the reward: a step is weighted by its own ratio, and the trace is cut
    where the target would not have taken the action. With ``rho = 1`` everywhere it is plain
    TD(lambda), as (8).

    Parameters
    ----------
    w : array_like, shape (n,)
    B : array_like, shape (L, n)
    r, rho : array_like, shape (L,)
    gamma_i, lambda_ : float
    alpha : float or array_like, shape (L,)
        Step size (per step: :func:`step_sizes`).
    rho_bar : float
        Truncation level of the ratios (1 in Retrace and V-trace).
    cap : float, optional
        Bound of the move of the episode's values per unit TD error (:func:`bounded_step`).

    Returns
    -------
    w : np.ndarray, shape (n,)
    delta : np.ndarray, shape (L,)
        TD errors.
    weight : np.ndarray, shape (L,)
        ``min(rho_bar, rho_l)``, the importance weight of each step's TD error.
    """
    w = np.array(w, dtype=np.float64)
    B = np.ascontiguousarray(B, dtype=np.float64)  # noqa: N806
    n_steps = B.shape[0]
    # Retrace / V-trace: rho_l and c_l = lambda min(c_bar, rho_l) truncated per step
    weight = np.minimum(np.asarray(rho, dtype=np.float64), rho_bar)
    alpha_l = np.broadcast_to(np.asarray(alpha, dtype=np.float64), (n_steps,)).tolist()
    r_list, wt = np.asarray(r, dtype=np.float64).tolist(), weight.tolist()
    e = np.zeros_like(w)
    delta = np.empty(n_steps)
    for l in range(n_steps):  # noqa: E741 - the paper's step index
        b = B[l]
        v_next = float(w @ B[l + 1]) if l + 1 < n_steps else 0.0
        d = r_list[l] + gamma_i * v_next - float(w @ b)
        if l:
            e *= gamma_i * lambda_ * wt[l - 1]     # trace cut by the previous step's ratio
        e += b
        a = alpha_l[l] if cap is None else bounded_step(alpha_l[l], cap, B, e)
        w += (a * wt[l] * d) * e
        delta[l] = d
    return w, delta, weight


def vtrace_targets(v: ArrayLike, r: ArrayLike, rho: ArrayLike, gamma_i: float,
                   lambda_: float, rho_bar: float = 1.0) -> np.ndarray:
    """V-trace targets (Espeholt et al. 2018, eq. 1) of one episode, backwards::

        v_l = V(x_l) + min(rho_bar, rho_l) delta_l + gamma_i c_l (v_{l+1} - V(x_{l+1}))
        delta_l = r_l + gamma_i V(x_{l+1}) - V(x_l),   c_l = lambda min(rho_bar, rho_l)

    with ``V(x_L) = v_L = 0`` (the episode ended).

    Parameters
    ----------
    v : array_like, shape (L,)
        ``V(x_l)`` at the current weights.
    r, rho : array_like, shape (L,)
    gamma_i, lambda_, rho_bar : float

    Returns
    -------
    np.ndarray, shape (L + 1,)
        ``v_0 .. v_{L-1}`` and ``v_L = 0``.
    """
    v = np.append(np.asarray(v, dtype=np.float64), 0.0)
    r = np.asarray(r, dtype=np.float64)
    wt = np.minimum(np.asarray(rho, dtype=np.float64), rho_bar)
    n_steps = len(r)
    target = np.zeros(n_steps + 1)
    for l in range(n_steps - 1, -1, -1):  # noqa: E741
        delta = r[l] + gamma_i * v[l + 1] - v[l]
        target[l] = v[l] + wt[l] * delta + gamma_i * lambda_ * wt[l] * (target[l + 1]
                                                                         - v[l + 1])
    return target


def offpac_weights(v: ArrayLike, r: ArrayLike, rho: ArrayLike, gamma_i: float,
                   lambda_: float, rho_bar: float = 1.0) -> np.ndarray:
    """Weight of each step's score in the off-policy actor-critic (beyond the paper).

    ``g_l = min(rho_bar, rho_l) (r_l + gamma_i v_{l+1} - V(x_l))``: the per-step truncated
    ratio (V-trace's actor, Espeholt et al. 2018) times the advantage against the module's own
    value as the baseline (Off-PAC, Degris et al. 2012), ``v`` the V-trace targets
    (:func:`vtrace_targets`). Replaces (9)'s ``sum_{l>=k} gamma^l r_l c_l``: no product of
    ratios, no return without a baseline.

    Parameters
    ----------
    v : array_like, shape (L,)
        ``V(x_l)`` before the update.
    r, rho : array_like, shape (L,)
    gamma_i, lambda_, rho_bar : float

    Returns
    -------
    np.ndarray, shape (L,)
    """
    v = np.asarray(v, dtype=np.float64)
    target = vtrace_targets(v, r, rho, gamma_i, lambda_, rho_bar)
    wt = np.minimum(np.asarray(rho, dtype=np.float64), rho_bar)
    # Off-PAC / V-trace actor: rho_l (r_l + gamma v_{l+1} - V(x_l)) d ln pi(x_l, u_l)
    return wt * (np.asarray(r, dtype=np.float64) + gamma_i * target[1:] - v)


def discounted_returns(r: ArrayLike, gamma_i: float) -> np.ndarray:
    """``G_l = sum_{k >= l} gamma_i^(k - l) r_k`` of one episode (``G_L = 0``), shape (L,)."""
    r = np.asarray(r, dtype=np.float64)
    g = np.empty(len(r))
    acc = 0.0
    for l in range(len(r) - 1, -1, -1):  # noqa: E741
        acc = r[l] + gamma_i * acc
        g[l] = acc
    return g


def imitation_weights(v: ArrayLike, r: ArrayLike, gamma_i: float, kappa: float) -> np.ndarray:
    """Weight of each step's score in the imitation term (module docstring, beyond the paper).

    ``kappa max(0, G_l - V(x_l))``: behaviour cloning of the executed action ``u_l`` (the score
    ``d ln pi(x_l, u_l)``, CRAIL, Uchibe 2018) where its return beat the module's own value
    (self-imitation learning, Oh et al. 2018), whoever acted.

    Parameters
    ----------
    v : array_like, shape (L,)
        ``V(x_l)`` before the update.
    r : array_like, shape (L,)
    gamma_i, kappa : float

    Returns
    -------
    np.ndarray, shape (L,)
    """
    # self-imitation: kappa max(0, G_l - V(x_l))
    return kappa * np.maximum(discounted_returns(r, gamma_i) - np.asarray(v, np.float64), 0.0)


def policy_step_scale(policy_step: str, v_max: float, sigma: float) -> tuple[float, float]:
    """Factors of the W and sigma scores of (10) (``GaussianPolicy.weighted_scores``, taken
    with respect to the dimensionless ``W`` of ``mean = v_max W b``) for the step of (9).

    ``paper``: (9) applied to (10) as printed, whose mean ``W_i b`` is in m/s. With
    ``W_i = v_max W``, ``W_i <- W_i + alpha g`` with ``g = d ln pi / d W_i = (u - mu) b^T /
    sigma^2`` is ``W <- W + alpha g / v_max``, and the score of ``W`` is ``v_max g``: the
    factor is ``1 / v_max^2``. ``dimensionless``: the gradient with respect to ``W`` itself
    (factor 1; v_max^2 times the paper's step: 11x for view, 64x for place). ``scaled``:
    ``sigma^2 / v_max^2`` on W and ``sigma^2 / (2 d)`` on sigma, the inverse Fisher information
    of the Gaussian (10) (beyond the paper). Sigma is in m/s in every case.

    Returns
    -------
    (float, float)
        Factors of the W score and of the sigma score.
    """
    if policy_step == 'paper':
        return 1.0 / v_max ** 2, 1.0
    if policy_step == 'dimensionless':
        return 1.0, 1.0
    if policy_step == 'scaled':
        return sigma ** 2 / v_max ** 2, sigma ** 2 / 4.0      # 2 d with d = 2 wheels
    raise ValueError(f'learner.policy_step: {policy_step!r} is not one of {POLICY_STEPS}')
