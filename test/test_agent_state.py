"""The learner's copy of the agent stream (clis_learner.core.agent_state): after each episode it
stands where every module and the arbiter stand, whatever history it is shown."""

from __future__ import annotations

from clis_base.agent_stream import AgentStream
from clis_base.instants import DecisionClock
from clis_learner.core.agent_state import AgentState
import numpy as np
import pytest

pytestmark = pytest.mark.bits

PERIODS = (0.25, 0.5, 1.2)
DT = 0.05
SEED = 7


def node_stream(selection: str) -> AgentStream:
    """A module node's stream: it draws at every instant it decides at, then ends."""
    return AgentStream(np.random.default_rng([SEED, 2]), len(PERIODS), selection,
                       DecisionClock(PERIODS, DT))


def run_node(stream: AgentStream, lengths: list[int]) -> list[str]:
    """The node's state after each episode of ``lengths`` ticks (it decided up to the end)."""
    out = []
    for k_end in lengths:
        stream.begin_episode()
        stream.instant(k_end)               # drew at the end tick too, before it heard the end
        stream.end_episode(k_end)
        out.append(stream.state())
    return out


def follow(agent: AgentState, lengths: list[int], first: int = 1, t0: float = 3.0) -> list:
    said = []
    for n, k_end in enumerate(lengths, first):
        agent.start(n, t0, DT)
        agent.end(n, t0 + k_end * DT)
        said.append(agent.announcement())
        t0 += (k_end + 1) * DT
    return said


@pytest.mark.parametrize('selection', ['episode', 'decision'])
def test_after_each_episode_the_learner_has_the_nodes_state(selection):
    lengths = [37, 5, 240, 1, 80]
    said = follow(AgentState(SEED, PERIODS, DT, selection), lengths)
    assert [s['agent_after'] for s in said] == [1, 2, 3, 4, 5]
    assert [s['agent_state'] for s in said] == run_node(node_stream(selection), lengths)
    # a resumed learner (its checkpoint after episode 2) goes on to the same states
    resumed = AgentState(SEED, PERIODS, DT, selection, said[1]['agent_state'], after=2)
    assert resumed.announcement() == said[1], 'the first start after the resume carries it'
    assert follow(resumed, lengths[2:], first=3) == said[2:]


def test_history_and_gaps():
    agent = AgentState(SEED, PERIODS, DT, 'episode')
    assert agent.announcement() == {}, "the run's own start: nothing to carry"
    said = follow(agent, [20, 30])
    # the episode topic's history again (a restarted learner sees it): nothing changes
    agent.start(1, 3.0, DT)
    agent.end(1, 4.0)
    agent.end(2, 9.0)
    assert agent.announcement() == said[-1]
    # an episode whose start was not seen: unknown from then on, nothing announced
    agent.end(3, 20.0)
    assert agent.announcement() == {}
    agent.start(4, 21.0, DT)
    agent.end(4, 22.0)
    assert agent.announcement() == {}
    # an end off the tick grid (a robot's own clock): unknown
    off = AgentState(SEED, PERIODS, DT, 'episode')
    off.start(1, 0.0, DT)
    off.end(1, 1.0123)
    assert off.announcement() == {}
    # while an episode runs there is nothing to carry yet
    running = AgentState(SEED, PERIODS, DT, 'episode')
    running.start(1, 0.0, DT)
    assert running.announcement() == {}
