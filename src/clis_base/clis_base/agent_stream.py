"""The agent's random stream: one generator, in the headless runner's call order, replayed by
every process of the graph that needs it (docs/design.md §6, "Random streams").

The headless runner draws every decision and every selection of a run from ONE generator
``default_rng([seed, 2])`` (the *agent stream*), in the order its loop makes them: at each tick
``k`` of an episode at which modules are due (:class:`~clis_base.instants.DecisionClock`),
two standard normals for each due module's proposal, in module order
(:meth:`clis_modules.core.decider.Decider.decide`), then one uniform for the arbiter's
selection (:class:`clis_modules.core.arbiter.Arbiter`) if it draws at ``k``: at the episode's
first instant (``k = 0``, where every module is due), and at every instant in ``decision``
mode. The episodes follow each other on the same generator.

What each call consumes of the generator depends only on the generator (not on the module's
state, features or parameters: ``standard_normal(2)`` whatever the width ``sigma`` or
``sigma_blind`` it is scaled by afterwards; one ``random()`` per selection, whatever the number
of available modules, one included). So the sequence of calls is fixed by the decision
instants and the episodes' lengths alone, and any process can make it: a module node, or the
arbiter node, makes every call of the run in that order and keeps its own draws
(:meth:`AgentStream.instant`; :mod:`clis_modules.core.draws`), and gets, bit for bit, the
numbers the runner's module (or arbiter) gets. The runner draws through the same object. The
simulator node makes the calls of each ended episode too (:meth:`AgentStream.end_episode`),
and announces the stream's state at each episode start (``agent_state``), so that a module
restarted mid-run, or a resumed run, goes on where the stream stands.

An episode that ends at tick ``k_end`` has its instants ``k < k_end`` (the runner does not
decide at the tick the episode ends on). A node may have decided at ``k_end`` before it heard
of the end: :meth:`AgentStream.end_episode` rewinds to the episode's start and replays exactly
the instants before ``k_end``.

Here in ``cr_sim`` (not with the modules) because the simulator node keeps it too, and
``cr_sim`` depends on no CLIS package.
"""

from __future__ import annotations

import json
import math

import numpy as np

from clis_base.instants import DecisionClock

__all__ = ['ACTION_DRAWS', 'AgentStream']

#: Standard normals of one proposal (the action u = (v_left, v_right)).
ACTION_DRAWS = 2
#: Ticks whose normals are drawn in one call (``episode`` selection: no uniform among them).
BLOCK_TICKS = 1200


class AgentStream:
    """The agent stream of a run (module docstring).

    Parameters
    ----------
    rng : np.random.Generator
        The agent generator (``default_rng([seed, 2])``).
    n : int
        Number of modules.
    selection : str
        ``arbiter.selection``: ``episode`` (one draw at ``k = 0``) or ``decision`` (one at
        every instant).
    clock : DecisionClock, optional
        The condition's decision instants (set :attr:`clock` before the first episode).
    fallback : np.random.Generator, optional
        A selection off the runner's instants (a node's arbiter after a timeout or a stale
        module: the graph is no longer the runner's then) draws from it; None: that is an
        error.
    """

    def __init__(self, rng: np.random.Generator, n: int, selection: str,
                 clock: DecisionClock | None = None,
                 fallback: np.random.Generator | None = None) -> None:
        self.rng = rng
        self.clock = clock
        self.selection = selection
        self.fallback = fallback
        self.normals = [np.zeros(ACTION_DRAWS) for _ in range(n)]
        self.uniform = math.nan
        self.pos = 0                           # the next tick to draw for
        self.start_state = rng.bit_generator.state
        self._prefix_clock: DecisionClock | None = None
        self._prefix: list[int] = []
        self._drop_block()

    def begin_episode(self) -> None:
        """An episode starts: its tick 0 is next."""
        self.pos = 0
        self.start_state = self.rng.bit_generator.state
        self._drop_block()

    # The normals of the ticks after tick 0 in ``episode`` mode (no uniform between them) are
    # drawn a block of ticks at a time: ``standard_normal(n)`` fills its array one normal
    # after the other, so the block holds the numbers, and leaves the generator in the state,
    # of its ticks' ``standard_normal(2)`` calls in order. Where the episode ends inside the
    # block, :meth:`end_episode` restores the generator to the block's start and draws only
    # the ticks before the end.

    def _drop_block(self) -> None:
        self._block = np.zeros(0)
        self._block_from = self._block_to = 0   # ticks [from, to) drawn into _block
        self._block_state: dict | None = None   # the generator before the block
        self._block_base = 0                    # _normals_before(_block_from)

    def _normals_before(self, k: int) -> int:
        """The normals of the ticks ``0 .. k - 1`` (tick 0 included), from the clock's
        schedule: per cycle of ticks, then the ticks of the last part cycle."""
        clock = self.clock
        if self._prefix_clock is not clock:
            prefix = [0]
            for due in clock.schedule:
                prefix.append(prefix[-1] + ACTION_DRAWS * len(due))
            self._prefix, self._prefix_clock = prefix, clock
        q, r = divmod(k, clock.cycle)
        return q * self._prefix[-1] + self._prefix[r]

    def _draw_block(self, k: int) -> None:
        """Draw the normals of the ticks ``k .. k + BLOCK_TICKS - 1`` in one call."""
        self._block_state = self.rng.bit_generator.state
        self._block_base = self._normals_before(k)
        self._block = self.rng.standard_normal(self._normals_before(k + BLOCK_TICKS)
                                               - self._block_base)
        self._block_from, self._block_to = k, k + BLOCK_TICKS

    def _take(self, j: int, k: int) -> None:
        """:meth:`_draw` of the ticks ``j .. k`` (``0 < j <= k``, the generator after the
        draws of the ticks before ``j`` or of the block) in ``episode`` mode: the normals of
        tick ``k`` from the block (ticks between are drawn and passed over)."""
        if self._block_state is None:
            self._draw_block(j)
        while k >= self._block_to:
            self._draw_block(self._block_to)
        due = self.clock.due_at(k)
        if due:
            o = self._normals_before(k) - self._block_base
            for i in due:
                self.normals[i] = self._block[o:o + ACTION_DRAWS]
                o += ACTION_DRAWS

    def _settle(self) -> None:
        """The generator after the draws of the ticks before :attr:`pos` and no others (a
        block drawn past it is given back)."""
        if self._block_state is not None and self.pos < self._block_to:
            self.rng.bit_generator.state = self._block_state
            n = self._normals_before(self.pos) - self._block_base
            if n:
                self.rng.standard_normal(n)
        self._drop_block()

    def _draw(self, k: int) -> None:
        due = self.clock.due_at(k)
        if not due:
            return
        rng = self.rng
        for i in due:
            self.normals[i] = rng.standard_normal(ACTION_DRAWS)
        if k == 0 or self.selection == 'decision':
            self.uniform = rng.random()

    def instant(self, k: int) -> None:
        """Make the draws of every instant up to tick ``k`` (those before it are passed over,
        those of ``k`` are kept: :attr:`normals` of the due modules, :attr:`uniform`). A tick
        already drawn for keeps its draws."""
        if k < self.pos:
            return
        j = self.pos
        if self.selection == 'decision' or self.clock is None:
            for tick in range(j, k + 1):
                self._draw(tick)
        else:
            if j == 0:
                self._draw(0)                  # every module's normals, then the uniform
                j = 1
            if k >= j:
                self._take(j, k)
        self.pos = k + 1

    def end_episode(self, k_end: int) -> None:
        """The episode ended at tick ``k_end``: the generator stands after the draws of its
        instants ``k < k_end``, and no others."""
        if self.pos > k_end:                   # drew at or past the end: replay from its start
            self._drop_block()
            self.rng.bit_generator.state = self.start_state
            self.pos = 0
        else:
            self._settle()
        for j in range(self.pos, k_end):
            self._draw(j)
        self.pos = 0
        self.start_state = self.rng.bit_generator.state

    def state(self) -> str:
        """The generator's state between episodes, as text (:meth:`set_state`)."""
        return json.dumps(self.start_state, sort_keys=True)

    def set_state(self, text: str) -> None:
        """Continue from :meth:`state` (a resumed run)."""
        self.rng.bit_generator.state = json.loads(text)
        self.begin_episode()
