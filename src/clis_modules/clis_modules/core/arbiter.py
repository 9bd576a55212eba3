"""Competitive module selection, eq. (3) (paper II-A).

``Pr(i | x) = exp(beta (1 - gamma_i) V_i(x)) / sum_j exp(beta (1 - gamma_j) V_j(x))``

``(1 - gamma_i) V_i`` is the value as a reward *rate* per decision of module i; with
``beta = 1`` and returns of at most 1 the exponents differ by at most ``1 - gamma_i`` (~0.02
to 0.11 with the default periods), so the selection is almost uniform (docs/design.md §2, 9).

Beyond the paper (``arbiter.rule = normalized``): ``Pr(i | x) ∝ exp(beta V_i(x) / s(x))`` with
``s(x) = max(max_j |V_j(x)|, scale_min)``, the values normalised by their scale. All modules
estimate the same objective (1) in the same units of time (11), so the value itself says which
module returns more; dividing by the scale makes ``beta`` a contrast (beta = 5: a module worth
20% less than the best is chosen e^-1 times as often) whatever the size of the returns, and
drops the ``(1 - gamma_i)`` weight that favours the slow modules 4.5x in Async. CRAIL (Uchibe
2018) likewise weights its mixture by the modules' performance.

Beyond the paper (``arbiter.bonus = kappa > 0``, with ``selection = episode``): an exploration
bonus where a module's value is uncertain because the module has seldom been chosen from
states like this one, ``Pr(i | x) ∝ exp(beta (V_i(x) / s(x) + kappa u_i(x)))`` with
``u_i(x) = 1 / sqrt(1 + n_i(x))`` (:func:`uncertainty`), ``n_i(x)`` the number of episodes
that module i was chosen to start from states whose features overlap ``b_i(x)`` (its
selection counts, :attr:`~clis_modules.core.modules.ModuleCore.visits`, updated by the learner
after each learning episode, frozen within one). The count-based bonus of UCB (Auer et al.
2002) and of count-based exploration (Strehl & Littman 2008; Bellemare et al. 2016), here on
the arbiter's choice: a learned module keeps acting from the starts where the innate one is
preferred until its own value there has been measured. Learning episodes only: an evaluation
draws without it. Headless only (``clis experiment``, ``clis study``): the node graph refuses
it (the counts do not travel to the module nodes).

When to select is an ambiguity of the paper (docs/design.md §2): ``episode`` (default) draws one
module at the episode start from the start-state values and keeps it -- what the importance
sampling of (4)-(6) assumes, one behaviour policy per episode; ``decision`` redraws at every
decision of any module, from each module's value at its latest features.

:class:`Selector` is the arbitration over streams of proposals (twist_mux style): it keeps the
latest :class:`~clis_modules.core.proposal.Proposal` of every module, draws by (3) when the
episode starts (once every module has proposed, or after ``start_timeout``) or at every
decision, drops a module whose latest proposal is older than ``stale_periods`` of its periods,
commands a stop when none is fresh, and clips the acting module's proposal to that module's
speed limit. The headless runner and the arbiter node drive the same object; only where its
inputs come from differs.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass as plain_dataclass
import math

from clis_base.params import ConfigError, dataclass, param
import numpy as np
from numpy.typing import ArrayLike

from clis_modules.core.proposal import Proposal

__all__ = ['ArbiterParams', 'selection_probs', 'uncertainty', 'count_start', 'refuse_bonus',
           'Arbiter', 'Command', 'Selector']


@dataclass(frozen=True)
class ArbiterParams:
    """Module selection (``clis.yaml`` section ``arbiter``)."""

    selection: str = param(choices=('episode', 'decision'),
                           doc='select once per episode or at every decision')
    stale_periods: float = param(1.0, 100.0, doc='a module whose latest proposal is older '
                                 'than this many of its periods is not selectable')
    start_timeout: float = param(0.0, 60.0, doc='at an episode start, wait at most this long '
                                 '[s] for every module to propose before drawing')
    rule: str = param(choices=('paper', 'normalized'),
                      doc="'paper' = (3) on (1 - gamma_i) V_i; 'normalized' = beta V_i / scale")
    scale_min: float = param(1e-6, 1e6, doc="smallest value scale of rule 'normalized'")
    explore: float = param(0.0, 1.0, doc='epsilon of an epsilon-soft selection: Pr(i|x) = '
                           '(1 - epsilon) rule + epsilon / (available modules); 0 = (3) alone')
    bonus: float = param(0.0, 10.0, off=0.0, doc='kappa of the exploration bonus kappa / '
                         'sqrt(1 + n_i(x)) added to the normalised values (selection = '
                         'episode; headless runner only); 0 = none')

    def __post_init__(self) -> None:
        if self.bonus > 0.0 and self.selection != 'episode':
            raise ConfigError(f'arbiter.bonus = {self.bonus} needs arbiter.selection = episode '
                             f'(got {self.selection!r}): the counts are of episode starts')


def refuse_bonus(bonus: float) -> None:
    """Raise for the exploration bonus in the node graph (the counts stay in the headless
    runner's modules: the module nodes would propose without them)."""
    if bonus > 0.0:
        raise ConfigError(f'arbiter.bonus = {bonus}: the exploration bonus runs in the headless '
                          'runner only (clis experiment, clis study); set arbiter.bonus: 0.0 '
                          'for the node graph')


def uncertainty(b: np.ndarray, visits: np.ndarray) -> float:
    """``u_i(x) = 1 / sqrt(1 + n_i(x))`` of the exploration bonus (module docstring).

    ``n_i(x) = |b| . C_i / sum |b|``, the selection counts ``C_i`` (the sum of ``|b_k| / sum
    |b_k|`` over the starts ``x_k`` module i was chosen from) read at the features ``b``:
    with one-hot features, the number of times module i was chosen from that cell; with
    overlapping features, a count weighted by the overlap.

    Parameters
    ----------
    b : np.ndarray, shape (n,)
        ``b_i(x)``.
    visits : np.ndarray, shape (n,)
        ``C_i``.
    """
    a = np.abs(b)
    mass = float(a.sum())
    n = float(a @ visits) / mass if mass > 0.0 else 0.0
    return 1.0 / math.sqrt(1.0 + n)


def count_start(visits: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The counts ``C_i`` of :func:`uncertainty` after module i was chosen from a start with
    features ``b``: ``C_i + |b| / sum |b|`` (a new array; unchanged for features all 0)."""
    a = np.abs(b)
    mass = a.sum()
    return visits + a / mass if mass > 0.0 else visits


def selection_probs(values: ArrayLike, gammas: ArrayLike, beta: float,
                    available: ArrayLike | None = None, rule: str = 'paper',
                    scale_min: float = 0.1, explore: float = 0.0,
                    bonus: ArrayLike | None = None) -> np.ndarray:
    """Selection probabilities of eq. (3) (``rule = 'paper'``) or of values normalised by
    their scale (``'normalized'``, module docstring).

    Parameters
    ----------
    values : array_like, shape (N,)
        ``V_i(x)`` of each module at its current features.
    gammas : array_like, shape (N,)
        ``gamma_i`` of each module (11).
    beta : float
        Inverse temperature, >= 0.
    available : array_like of bool, shape (N,), optional
        Modules that currently propose an action; the others get probability 0.
    rule : str
        ``paper`` or ``normalized``.
    scale_min : float
        Smallest scale ``s`` of ``normalized``.
    explore : float
        Beyond the paper: ``epsilon`` of an epsilon-soft selection (Sutton & Barto 2018,
        Sec. 5.4), ``(1 - epsilon) Pr(i|x) + epsilon / n`` over the ``n`` available modules:
        every module keeps acting, and learning from its own actions, where the values favour
        another (0: the rule alone, bit for bit).
    bonus : array_like, shape (N,), optional
        Beyond the paper: ``kappa u_i(x)`` of each module (:func:`uncertainty`), added to the
        rule's exponent in units of ``beta``: ``beta (V_i / s + kappa u_i)`` (None: none).

    Returns
    -------
    np.ndarray, shape (N,)
        ``Pr(i | x)``, summing to 1 (computed with the max subtracted: no overflow).

    Raises
    ------
    ValueError
        If no module is available or an available module has a non-finite value.
    """
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    g = np.asarray(gammas, dtype=np.float64).reshape(-1)
    ok = np.ones(v.shape, bool) if available is None else np.asarray(available, bool).reshape(-1)
    if not (v.shape == g.shape == ok.shape):
        raise ValueError('values, gammas and available must have the same length')
    if not ok.any():
        raise ValueError('no module is available for selection')
    if not np.all(np.isfinite(v[ok])):
        raise ValueError(f'non-finite module value in {v}')
    z = np.full(v.shape, -np.inf)
    if rule == 'paper':
        # (3) Pr(i|x) ∝ exp(beta (1 - gamma_i) V_i(x))
        z[ok] = beta * (1.0 - g[ok]) * v[ok]
    elif rule == 'normalized':
        # beyond the paper: Pr(i|x) ∝ exp(beta V_i(x) / max(max_j |V_j(x)|, scale_min))
        z[ok] = beta * v[ok] / max(float(np.max(np.abs(v[ok]))), scale_min)
    else:
        raise ValueError(f"unknown selection rule {rule!r}: 'paper' or 'normalized'")
    if bonus is not None:
        # beyond the paper: Pr(i|x) ∝ exp(beta (V_i(x) / s(x) + kappa u_i(x)))
        z[ok] += beta * np.asarray(bonus, dtype=np.float64).reshape(-1)[ok]
    p = np.exp(z - z[ok].max())
    p /= p.sum()
    if explore > 0.0:
        # epsilon-soft: (1 - epsilon) Pr(i|x) + epsilon / n over the available modules
        p = (1.0 - explore) * p + explore * ok / ok.sum()
    return p


class Arbiter:
    """Picks the acting module by (3), once per episode or at every decision.

    Parameters
    ----------
    params : ArbiterParams
    beta : float
        Inverse temperature of (3).
    rng : np.random.Generator
        The only source of randomness (one ``rng.random()`` per draw).

    Attributes
    ----------
    current : int or None
        Index of the acting module.
    probs : np.ndarray or None
        Probabilities of the last draw, shape (N,).
    """

    def __init__(self, params: ArbiterParams, beta: float, rng: np.random.Generator) -> None:
        self.mode = params.selection
        self.rule, self.scale_min = params.rule, params.scale_min
        self.explore = params.explore
        self.beta = float(beta)
        self.rng = rng
        self.current: int | None = None
        self.probs: np.ndarray | None = None

    def _draw(self, values: ArrayLike, gammas: ArrayLike, available: ArrayLike | None,
              bonus: ArrayLike | None = None) -> int:
        self.probs = selection_probs(values, gammas, self.beta, available, self.rule,
                                     self.scale_min, self.explore, bonus)
        cdf = np.cumsum(self.probs)
        i = min(int(np.searchsorted(cdf, self.rng.random() * cdf[-1], side='right')),
                len(cdf) - 1)
        if self.probs[i] == 0.0:             # rounding at the top edge: last available one
            i = int(np.flatnonzero(self.probs)[-1])
        self.current = i
        return i

    def begin_episode(self, values: ArrayLike, gammas: ArrayLike,
                      available: ArrayLike | None = None,
                      bonus: ArrayLike | None = None) -> int:
        """Draw the acting module at the episode start (both modes; ``bonus``: the
        exploration bonus of each module, or None); returns its index."""
        return self._draw(values, gammas, available, bonus)

    def on_decision(self, values: ArrayLike, gammas: ArrayLike,
                    available: ArrayLike | None = None) -> int:
        """At a decision of any module: ``decision`` mode redraws; ``episode`` mode keeps the
        current module unless it is no longer available (then redraws among the others)."""
        if self.mode == 'decision' or self.current is None:
            return self._draw(values, gammas, available)
        if available is not None and not np.asarray(available, bool)[self.current]:
            return self._draw(values, gammas, available)
        return self.current


@plain_dataclass(frozen=True)
class Command:
    """What the robot executes from time ``t`` on (the output of :class:`Selector`).

    Attributes
    ----------
    t : float
        Time from which the command is in force [s] (the decision that produced it).
    module : int
        Index of the acting module; -1 when no module is fresh (stop).
    u : np.ndarray, shape (2,)
        The acting module's proposal ``(v_left, v_right)`` [m/s], not clipped (zeros on stop).
    u_exec : np.ndarray, shape (2,)
        What the wheels get: ``u`` clipped to the acting module's speed limit.
    drawn : bool
        Whether a selection by (3) was drawn at this decision (then :attr:`Selector.probs`).
    """

    t: float
    module: int
    u: np.ndarray
    u_exec: np.ndarray
    drawn: bool


class Selector:
    """Arbitration over streams of proposals (module docstring).

    Parameters
    ----------
    names : sequence of str
        Module names, in index order.
    gammas, v_max, periods : array_like, shape (N,)
        ``gamma_i`` (11), speed limits [m/s] and decision periods [s] of the modules.
    params : ArbiterParams
    beta : float
        Inverse temperature of (3).
    rng : np.random.Generator
        Draws the selections.

    Attributes
    ----------
    acting : int
        Index of the acting module (-1 before the first draw of an episode or when stopped).
    probs, values : np.ndarray or None
        ``Pr(i | x)`` and ``V_i`` of the last draw, shape (N,).
    start_probs, start_values : np.ndarray or None
        The same at the episode's first draw.
    explore_now : bool
        Whether the exploration bonus (``params.bonus``) enters this episode's first draw
        (learning episodes; the runner sets it, an evaluation draws without it).
    """

    def __init__(self, names: Sequence[str], gammas: ArrayLike, v_max: ArrayLike,
                 periods: ArrayLike, params: ArbiterParams, beta: float,
                 rng: np.random.Generator) -> None:
        self.names = tuple(names)
        self.index = {n: i for i, n in enumerate(self.names)}
        self.gammas = np.asarray(gammas, dtype=np.float64)
        self.v_max = np.asarray(v_max, dtype=np.float64)
        self._v_max = self.v_max.tolist()
        self.max_age = params.stale_periods * np.asarray(periods, dtype=np.float64)
        self._max_age = self.max_age.tolist()
        self.start_timeout = params.start_timeout
        self.kappa = params.bonus
        self.explore_now = self.kappa > 0.0
        self.arbiter = Arbiter(params, beta, rng)
        self.latest: list[Proposal | None] = [None] * len(self.names)
        self.running = False
        self.waiting = False
        self.t0 = 0.0
        self.acting = -1
        self.values: np.ndarray | None = None
        self.start_probs: np.ndarray | None = None
        self.start_values: np.ndarray | None = None

    @property
    def mode(self) -> str:
        return self.arbiter.mode

    @property
    def probs(self) -> np.ndarray | None:
        return self.arbiter.probs

    def begin_episode(self, t0: float) -> None:
        """An episode starts at ``t0``: forget the proposals, wait for the first draw."""
        self.t0 = float(t0)
        self.latest = [None] * len(self.names)
        self.running = self.waiting = True
        self.acting = -1
        self.arbiter.current = None
        self.start_probs = self.start_values = None

    def end_episode(self, t: float | None = None) -> Command:
        """The episode ended (at ``t``; default its start): stop until the next
        :meth:`begin_episode`."""
        self.running = self.waiting = False
        self.acting = -1
        return self._stop(self.t0 if t is None else t)

    def fresh(self, now: float) -> np.ndarray:
        """Which modules are selectable at ``now``: a proposal of this episode, not older
        than ``stale_periods`` periods. Shape (N,), bool."""
        return np.array([self._fresh_one(i, now) for i in range(len(self.names))], dtype=bool)

    def _fresh_one(self, i: int, now: float) -> bool:
        """Whether module ``i`` is selectable at ``now`` (:meth:`fresh`)."""
        p = self.latest[i]
        return p is not None and p.t >= self.t0 - 1e-9 and now - p.t <= self._max_age[i]

    def on_proposals(self, proposals: Sequence[Proposal], now: float) -> Command | None:
        """New proposals (decided at the same instant) at time ``now``; the new command, or
        None if the command in force does not change."""
        if not proposals:
            return None
        t = proposals[0].t                   # their latest time: max(p.t for p in proposals)
        i = self.acting
        name = self.names[i] if i >= 0 else None
        acting_due = False
        for p in proposals:
            self.latest[self.index[p.module]] = p
            t = max(t, p.t)
            acting_due = acting_due or p.module == name
        if not self.running:
            return None
        if not self.waiting and self.mode == 'episode' and i >= 0 and self._fresh_one(i, now):
            # the acting module is still fresh: it keeps acting (as below, without every
            # module's freshness)
            if acting_due:
                return self._command(t, i, drawn=False)
            return None
        ok = self.fresh(now)
        if self.waiting:
            if not ok.all() and now < self.t0 + self.start_timeout:
                return None
            return self._draw(t, ok, start=True)
        due = {self.index[p.module] for p in proposals}
        if self.mode == 'decision':
            return self._draw(t, ok, start=False)
        if not ok[self.acting]:
            return self._draw(t, ok, start=False)
        if self.acting in due:
            return self._command(t, self.acting, drawn=False)
        return None

    def check(self, now: float) -> Command | None:
        """Time passes without proposals: draw once the start wait is over; replace an
        acting module gone stale; stop when no module is fresh."""
        if not self.running:
            return None
        ok = self.fresh(now)
        if self.waiting:
            if now >= self.t0 + self.start_timeout and ok.any():
                return self._draw(now, ok, start=True)
            return None
        if self.acting >= 0 and ok[self.acting]:
            return None
        if ok.any():
            return self._draw(now, ok, start=False)
        if self.acting == -1:
            return None                                  # already stopped
        self.acting = -1
        return self._stop(now)

    # ------------------------------------------------------------------ internals

    def _values(self) -> np.ndarray:
        return np.array([p.value if p is not None else 0.0 for p in self.latest])

    def _draw(self, t: float, ok: np.ndarray, start: bool) -> Command | None:
        if not ok.any():
            if self.acting == -1:
                return None
            self.acting = -1
            return self._stop(t)
        self.values = self._values()
        if start:
            bonus = None
            if self.explore_now:
                # beyond the paper: kappa u_i(x_0), each module's uncertainty at the start
                bonus = self.kappa * np.array([p.uncertainty if p is not None else 0.0
                                               for p in self.latest])
            i = self.arbiter.begin_episode(self.values, self.gammas, ok, bonus)
            self.start_probs, self.start_values = self.arbiter.probs.copy(), self.values
            self.waiting = False
        else:
            i = self.arbiter.on_decision(self.values, self.gammas, ok)
        return self._command(t, i, drawn=True)

    def _command(self, t: float, i: int, drawn: bool) -> Command:
        self.acting = i
        u = self.latest[i].u
        v = self._v_max[i]
        # the robot executes the acting proposal within its speed limit (docs/design.md §3)
        # = np.minimum(np.maximum(u, -v), v) on the two components as Python floats (the
        # same comparisons: NaN kept, v > 0)
        u0, u1 = u.tolist()
        return Command(float(t), i, u, np.array((min(max(u0, -v), v), min(max(u1, -v), v))),
                       drawn)

    def _stop(self, t: float) -> Command:
        return Command(float(t), -1, np.zeros(2), np.zeros(2), False)
