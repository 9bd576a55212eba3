"""The learner's topics into its :class:`~clis_learner.core.intake.EpisodeStream`: the one
routing of the live learner node (:mod:`clis_learner.learner_node`) and of ``clis learn``
reading a bag (:func:`clis_app.bags.commands.feed_stream`).

Each module's ``NAME/proposal`` and ``NAME/observation``, the arbiter's ``arbiter/action``
and ``arbiter/selection``, the robot's ``reward`` (:data:`RECORDS`, :func:`feed_record`) and
the ``episode`` events (:func:`feed_episode`), decoded by the conversions of the nodes that
publish them. The headless runner makes the same records itself and feeds the stream
directly.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import math
from typing import Any

from clis_modules.module_node import END_EVENTS
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Vector3Stamped
from sensor_msgs.msg import JointState

from clis_learner.core.intake import Closed, EpisodeStream
from clis_modules import conversions as mconv
from cr_sim import conversions as rconv

__all__ = ['EPISODE', 'RECORDS', 'EpisodeEvent', 'feed_episode', 'feed_record',
           'record_topics']

#: The record streams: ``(kind, topic, message type)``; ``{name}``: each module's (its
#: observations only with more than one module: the behaviour's state of another's instant).
RECORDS = (('proposal', '{name}/proposal', JointState),
           ('observation', '{name}/observation', JointState),
           ('action', 'arbiter/action', JointState),
           ('selection', 'arbiter/selection', JointState),
           ('reward', 'reward', Vector3Stamped))
#: The episode events: ``(topic, message type)``.
EPISODE = ('episode', DiagnosticArray)


def record_topics(names: Sequence[str], namespace: str = '') -> list[tuple[str, str, type]]:
    """``(kind, topic, type)`` of every record stream of modules ``names``; topics relative,
    or under ``namespace`` (``'/'``: absolute)."""
    ns = ''
    if namespace:
        ns = '/' + namespace.strip('/') + '/' if namespace.strip('/') else '/'
    out = []
    for kind, topic, msg_type in RECORDS:
        if kind == 'observation' and len(names) < 2:
            continue
        for name in (names if '{name}' in topic else [None]):
            out.append((kind, ns + topic.format(name=name), msg_type))
    return out


def feed_record(stream: EpisodeStream, kind: str, msg: Any) -> None:
    """A record message of stream ``kind`` into ``stream``. Raises ValueError (an unreadable
    proposal) or KeyError (a module not of the condition): the caller says or ignores it."""
    if kind == 'proposal':
        stream.proposal(mconv.proposal_from_msg(msg))
    elif kind == 'observation':
        name, t, b = mconv.observation_from_msg(msg)
        if name not in stream.names:
            raise KeyError(name)
        stream.observation(name, t, b)
    elif kind == 'action':
        stream.action(*mconv.action_from_msg(msg))
    elif kind == 'selection':
        t, _, probs, values = mconv.selection_from_msg(msg)
        stream.selection(t, probs, values)
    elif kind == 'reward':
        t, r, _ = rconv.reward_from_msg(msg)
        stream.reward(t, r)
    else:
        raise ValueError(f'not a record stream: {kind!r}')


@dataclass
class EpisodeEvent:
    """What an episode event did: its stamp, name (``start``, ``reached`` ...), episode
    number and values; the episode it closed (a start closes an ended one still open) and the
    row of an ended episode whose start was not seen (nothing to learn)."""

    t: float
    event: str
    index: int
    values: dict[str, str]
    closed: Closed | None = None
    skipped: dict[str, Any] | None = None


def feed_episode(stream: EpisodeStream, msg: DiagnosticArray, deadline: float = math.inf,
                 grace: float = 0.0) -> EpisodeEvent:
    """An ``episode`` event into ``stream``: a start (with the tick ``dt`` it announces), or
    an end (``deadline``, ``grace``: :meth:`EpisodeStream.end`)."""
    t, event, values = rconv.episode_from_msg(msg)
    out = EpisodeEvent(t, event, int(values.get('episode', -1)), values)
    if event == 'start':
        out.closed = stream.start(t, out.index, values.get('start', ''),
                                  float(values['dt']) if 'dt' in values else None)
    elif event in END_EVENTS:
        out.skipped = stream.end(t, out.index, event, deadline, grace,
                                 float(values.get('episode_return', 'nan')))
    return out
