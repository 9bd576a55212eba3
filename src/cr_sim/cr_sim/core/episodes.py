"""Episodes as the robot interface reports them, for the simulator and the real robot alike.

Both robots (the ``sim`` node, :mod:`cr_sim.core.sim_episodes`; the bridge,
:mod:`cr_bridge.core.episode`) number their episodes, report each one's start and end on the
``episode`` topic, sum its rewards and hold the next start behind the learner gate
(:class:`~cr_sim.core.gate.EpisodeGate`). :class:`EpisodeBook` is that bookkeeping, once:

- **numbering**: learning episodes are numbered from 1, and a resumed run goes on from
  ``first_episode`` (docs/design.md §6, "Numbering"); :attr:`EpisodeBook.episode` is the last
  episode started (``first_episode - 1`` before the first);
- **start**: ``start`` with ``episode``, the robot's own values, then ``params_version`` (the
  learner's parameter version, under the learner gate: the modules wait for it);
- **rewards**: the return reported with the end and with each reward is the undiscounted sum of
  the episode's rewards, ``R = sum_k r_k`` (every module discounts it with its own ``gamma_i``
  when it learns, eqs. (1) and (8) of Uchibe & Doya);
- **end**: ``reached`` / ``timeout`` / ``reset`` with ``episode``, ``episode_return``,
  ``duration``, then the robot's own values; at most once per episode (an end with no episode
  running reports nothing);
- **learner gate**: before the first episode and after each end, whether the next one may start
  (:attr:`EpisodeBook.ready`).

The text format of a resume state (:func:`format_resume_state`, :func:`parse_resume_state`) is
here too: hex floats then the random streams' states as URL-safe base64 of their JSON, exact to
the bit (``node.resume_state`` of the simulator, from the end event of the episode before).

Pure: no ROS, times are passed in (wall seconds for the gate, the robot's clock for events).
"""

from __future__ import annotations

import base64
from collections.abc import Sequence
from dataclasses import dataclass, field
import json
from typing import Any

from cr_sim.core.gate import EpisodeGate

__all__ = ['Event', 'EpisodeBook', 'format_resume_state', 'parse_resume_state']


@dataclass(frozen=True)
class Event:
    """An episode event: ``start`` / ``reached`` / ``timeout`` / ``reset`` at ``t``.

    Attributes
    ----------
    name : str
    t : float
        The robot's clock [s] (the simulator's ``/clock``, the robot's device time).
    values : dict
        Its key/values, in the order the ``episode`` message carries them.
    """

    name: str
    t: float
    values: dict[str, Any] = field(default_factory=dict)


class EpisodeBook:
    """Numbering, start and end reports, return and learner gate (module docstring).

    Parameters
    ----------
    gate : EpisodeGate
        Its learner (and graph) gate decides when the next episode may start.
    first_episode : int
        Number of the first episode this book starts (> 1: a resumed run).

    Attributes
    ----------
    episode : int
        The last episode started (``first_episode - 1`` before the first).
    t0 : float
        The running (or last) episode's start on the robot's clock [s] (0 before the first).
    ret : float
        Its return so far, ``sum_k r_k``.
    running : bool
        An episode runs (started, not yet ended).
    ready : bool
        The gate let the next episode start (cleared by :meth:`start`).
    """

    def __init__(self, gate: EpisodeGate, first_episode: int = 1) -> None:
        if first_episode < 1:
            raise ValueError(f'first_episode = {first_episode}: episodes are numbered from 1')
        self.gate = gate
        self.first_episode = first_episode
        self.episode = first_episode - 1
        self.t0 = 0.0
        self.ret = 0.0
        self.running = False
        self.ready = False

    @property
    def started_any(self) -> bool:
        """Whether this book started an episode already."""
        return self.episode >= self.first_episode

    # ------------------------------------------------------------------ the learner gate

    def first(self, now: float, ready: bool = True) -> bool:
        """Before the first episode, at wall time ``now``: whether it may start at once
        (:meth:`EpisodeGate.first`; ``ready``: the graph's subscribers are matched)."""
        self.ready = self.gate.first(now, ready)
        return self.ready

    def poll(self, now: float, ready: bool = True) -> tuple[str | None, str | None]:
        """:meth:`EpisodeGate.poll` at wall time ``now``: ``(action, warning)``; the action
        ``'start'`` makes the book :attr:`ready`."""
        action, warning = self.gate.poll(now, ready)
        if action == 'start':
            self.ready = True
        return action, warning

    def release(self, now: float) -> bool:
        """After an end, at wall time ``now``: whether the next episode may start at once
        (:meth:`EpisodeGate.ended`), else the gate holds it until :meth:`poll` says
        ``'start'``."""
        self.ready = self.gate.ended(self.episode, now)
        return self.ready

    # ------------------------------------------------------------------ the episodes

    def start(self, t: float, **values: Any) -> Event:
        """The next episode starts at ``t``: its ``start`` event, ``episode`` first, then
        ``values``, then ``params_version`` under the learner gate."""
        self.episode += 1
        self.t0 = t
        self.ret = 0.0
        self.running = True
        self.ready = False
        out: dict[str, Any] = {'episode': self.episode, **values}
        if self.gate.wait_for_learner:
            out['params_version'] = self.gate.version
        self.gate.started(self.episode, t)
        return Event('start', t, out)

    def add(self, reward: float) -> float:
        """A reward of the running episode: the return so far, ``R <- R + r``."""
        self.ret += reward
        return self.ret

    def end(self, name: str, t: float, duration: float, **values: Any) -> Event | None:
        """The running episode ends at ``t`` after ``duration`` [s]: its ``name`` event
        (``episode``, ``episode_return``, ``duration``, then ``values``); None, and nothing
        changes, if no episode runs (an end is reported once)."""
        if not self.running:
            return None
        self.running = False
        return Event(name, t, {'episode': self.episode, 'episode_return': self.ret,
                               'duration': duration, **values})


# ---------------------------------------------------------------------- resume state text

def format_resume_state(values: Sequence[float], streams: dict[str, Any]) -> str:
    """``values`` as hex floats (exact), then ``streams`` (the random generators' states,
    plain JSON) as URL-safe base64 of their JSON with sorted keys, separated by spaces."""
    packed = base64.urlsafe_b64encode(json.dumps(streams, sort_keys=True).encode())
    return ' '.join([*(float(v).hex() for v in values), packed.decode()])


def parse_resume_state(text: str, n_values: int) -> tuple[list[float], dict[str, Any]]:
    """The ``(values, streams)`` of :func:`format_resume_state`.

    Raises
    ------
    ValueError
        Not ``n_values`` hex floats and one base64 word, or not their format.
    """
    words = text.split()
    if len(words) != n_values + 1:
        raise ValueError(f'{len(words)} values, expected {n_values + 1}')
    values = [float.fromhex(v) for v in words[:n_values]]
    streams = json.loads(base64.urlsafe_b64decode(words[n_values]))
    return values, streams
