"""The agent stream's draws as the generators the modules' deciders and the arbiter call.

:class:`~clis_base.agent_stream.AgentStream` (the one implementation of the runner's call order,
kept in ``cr_sim`` because the simulator node replays it too) makes the draws of each decision
instant; :class:`ModuleDraws` hands a :class:`~clis_modules.core.decider.Decider` its module's
two normals of the instant, :class:`SelectionDraws` the arbiter its uniform. The headless
runner and the module and arbiter nodes use them alike.
"""

from __future__ import annotations

import math

from clis_base.agent_stream import AgentStream
import numpy as np

from clis_modules.core.policy import ACTION_DIM

__all__ = ['AgentStream', 'ModuleDraws', 'SelectionDraws', 'module_draws', 'selection_draws']


def module_draws(stream: AgentStream, i: int) -> ModuleDraws:
    """Module ``i``'s draws, as the generator its Decider calls."""
    return ModuleDraws(stream, i)


def selection_draws(stream: AgentStream) -> SelectionDraws:
    """The arbiter's draws, as the generator its Arbiter calls."""
    return SelectionDraws(stream)


class ModuleDraws:
    """What a :class:`~clis_modules.core.decider.Decider` calls instead of a generator: the
    normals of its module at the current instant (:meth:`AgentStream.instant` first)."""

    def __init__(self, stream: AgentStream, i: int) -> None:
        self.stream, self.i = stream, i

    def standard_normal(self, size: int = ACTION_DIM) -> np.ndarray:
        assert size == ACTION_DIM
        return self.stream.normals[self.i]


class SelectionDraws:
    """What an :class:`~clis_modules.core.arbiter.Arbiter` calls instead of a generator: the
    uniform of the current instant."""

    def __init__(self, stream: AgentStream) -> None:
        self.stream = stream

    def random(self) -> float:
        u = self.stream.uniform
        if math.isnan(u):
            if self.stream.fallback is not None:
                return float(self.stream.fallback.random())
            raise RuntimeError('a selection where the agent stream has none (the arbiter '
                               "drew off the runner's instants)")
        self.stream.uniform = math.nan
        return u
