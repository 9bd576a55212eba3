"""EpisodeStream (core/stream.py): the learner node's episode logic, shared with ``clis learn``.

Records of two episodes arrive shuffled across streams (as from several topics); the stream
learns exactly what the Learner learns from each episode's memory; an episode whose start was
not in the stream is not learned; closing waits for the last reward or the deadline."""

from __future__ import annotations

import copy

from clis_learner.core.config import load_clis_params
from clis_learner.core.intake import EpisodeStream
from clis_learner.core.learner import Learner
from clis_learner.core.memory import EpisodeMemory, StreamBuffer, episode_time
from clis_modules.core.modules import make_modules
from clis_modules.core.proposal import Proposal
import numpy as np
import pytest

# results pinned bit for bit: tools/cpu_check.py runs these under each CPU kernel set
pytestmark = pytest.mark.bits

LANDMARKS = np.array([[1.5, 0.75], [-0.75, 1.5], [-1.5, -0.75], [0.75, -1.5]])


def _records(mods, t0: float, seconds: float, seed: int):
    """Decisions, actions and rewards of one view-only episode from ``t0`` (a list of calls)."""
    rng = np.random.default_rng(seed)
    out = []
    m = mods[0]
    for k in range(int(seconds / m.period)):
        t = t0 + k * m.period
        b = m.features(rng.uniform(-3, 3), rng.uniform(0, 0.5), None)
        u = m.sample(b, rng)
        out.append(('proposal', Proposal(m.name, t, b, u, u, m.sigma, 0.0, 0)))
        out.append(('action', (t, u, m.name)))
    for k in range(1, int(seconds / 0.05) + 1):
        out.append(('reward', (t0 + k * 0.05, -0.1 if rng.random() < 0.05 else 0.0)))
    return out


def _feed(stream, records, rng):
    order = rng.permutation(len(records))                  # any arrival order
    for i in order:
        kind, value = records[i]
        if kind == 'proposal':
            stream.proposal(value)
        elif kind == 'action':
            stream.action(*value)
        else:
            stream.reward(*value)


def test_stream_learns_what_the_learner_learns_from_each_episode():
    params = load_clis_params()
    mods = make_modules(params, 'view', LANDMARKS, 1.5)
    twin = copy.deepcopy(mods)
    stream = EpisodeStream(mods, params, 'view', 0)
    rng = np.random.default_rng(1)
    learner = Learner(twin, params)
    for ep, t0 in ((1, 0.0), (2, 10.0)):
        recs = _records(mods, t0, 6.0, seed=ep)
        assert stream.start(t0, ep, 'A') is None
        _feed(stream, recs, rng)
        assert stream.end(t0 + 6.0, ep, 'timeout') is None
        assert stream.due(0.0) == (False, [])               # the arbiter's stop is missing
        stream.action(t0 + 6.0, np.zeros(2), '')            # the stop at the end
        assert stream.due(0.0) == (True, [])                # everything in, no grace
        closed = stream.close()
        assert closed.learned and closed.episode == ep and stream.version == ep
        # the same episode straight into a memory and the Learner
        mem = EpisodeMemory(['view'])
        mem.t_start = t0
        for kind, v in sorted(recs, key=lambda r: (r[1].t if r[0] == 'proposal' else r[1][0])):
            if kind == 'proposal':
                mem.record_decision('view', v.t, v.b)
            elif kind == 'action':
                mem.record_action(*v)
            else:
                mem.record_reward(*v)
        mem.end(t0 + 6.0, False)
        learner.learn(mem)
        np.testing.assert_allclose(mods[0].w, twin[0].w, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(mods[0].W, twin[0].W, rtol=1e-12, atol=1e-15)
    assert np.abs(mods[0].w).max() > 0


def test_episode_not_seen_from_its_start_is_not_learned_and_closing_waits():
    params = load_clis_params()
    mods = make_modules(params, 'view', LANDMARKS, 1.5)
    stream = EpisodeStream(mods, params, 'view', 0)
    # the stream begins 2 s into episode 3: its end is reported, nothing learned
    assert stream.end(5.0, 3, 'timeout') == {'episode': 3, 'learned': 0, 'event': 'timeout'}
    # episode 4 starts, but the first reward this stream saw is older than its start + period:
    # fine; one that started before the stream's first reward is not learnable
    stream.reward(20.0, 0.0)
    stream.start(10.0, 4, 'B')                              # started before the first reward
    stream.end(26.0, 4, 'reached', deadline=100.0, grace=1.0)
    assert stream.due(0.5) == (False, [])                   # its last reward has not come
    close, missing = stream.due(100.0)                      # deadline: what is missing
    assert close and 'the last reward' in missing
    closed = stream.close()
    assert not closed.learned and stream.version == 0
    with pytest.raises(RuntimeError):
        stream.close()
    with pytest.raises(KeyError):
        stream.action(1.0, np.zeros(2), 'place')            # not of the condition


def test_a_cut_episode_counts_its_times_in_ticks_from_its_start():
    """The graph's stamps (nanoseconds, absolute) become the headless simulator's ``k dt``."""
    dt = 0.05
    assert episode_time(20.05 + 1.2, 20.05, dt) == 24 * dt != 1.2    # 1.2000000000000002
    assert episode_time(20.05 + 0.0123, 20.05, dt) == pytest.approx(0.0123)   # off the grid
    assert episode_time(3.0, 1.0, 0.0) == 3.0
    buf = StreamBuffer(['innate'])
    t0 = 20.05
    for k in (0, 24, 48):
        buf.add_decision('innate', t0 + k * dt, np.ones(3))
        buf.add_action(t0 + k * dt, np.array([0.1, 0.2]), 'innate')
    buf.add_reward(t0 + 30 * dt, -0.1)
    mem = buf.cut(t0, t0 + 60 * dt, False, dt=dt)
    t, _ = mem.decisions('innate')
    assert t.tolist() == [0.0, 24 * dt, 48 * dt]
    assert mem.actions()[0].tolist() == [0.0, 24 * dt, 48 * dt]
    assert mem.rewards()[0].tolist() == [30 * dt]
    assert mem.duration == 60 * dt
