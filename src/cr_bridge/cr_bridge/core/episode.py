"""The episode logic on the real robot: what the simulator gets for free, from the sensors.

In the simulator the episode end, the rewards and the next start come from ground truth. On the
robot the bridge derives them from what the robot senses, frame by frame, with the simulator's
rules and parameters (``config/sim.yaml`` sections ``episode`` and ``wander``):

* **destination reached**: the omni-camera sees the destination blob and its range estimate
  is within the arena's ``goal_radius`` -> ``reward_goal`` and the episode ends (``reached``);
  a robot driven by its profile (:mod:`cr_bridge.core.ros_robot`) reaches it by the blob's
  apparent width instead (``goal_width``, rule ``size``), or by the scan's return in its
  bearing within ``goal_radius`` (rule ``range``);
* **collision**: a new contact (not in contact at the previous frame, in contact now) ->
  ``reward_collision`` once, nothing more while it stays pressed (the simulator's rule). Contact
  = the bump switch, or (if enabled) the accelerometer's horizontal magnitude above
  ``accel_threshold``, or (if enabled) an IR reading below ``ir_contact`` (a robot driven by
  its profile: a scan sector below ``collision_range``);
* **time limit**: ``time_limit`` s of device time after the start -> ``timeout``;
* **next start**: between episodes the robot drives itself with the simulator's hand-made
  wander policy (:class:`cr_sim.core.wander.WanderPolicy`, reused as is) for at least
  ``wander_time`` s, until the learner has learned from the last episode (the learner gate of
  :class:`cr_sim.core.gate.EpisodeGate`, reused) and outside the goal; then the next episode
  starts where it stands.

Rewards are reported on every frame of an episode after its first (as the simulator reports
one per step), the first frame of an episode is its start instant.

What the robot shares with the simulator is the simulator's: the numbering, the start and end
events, the return and the learner gate are :class:`cr_sim.core.episodes.EpisodeBook`, the
events :class:`cr_sim.core.episodes.Event`; only the rules above are the robot's.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math

from clis_base.params import dataclass as frozen_dataclass
from clis_base.params import param
from cr_sim.core.episodes import EpisodeBook, Event
from cr_sim.core.gate import EpisodeGate
from cr_sim.core.observation import Observation
from cr_sim.core.sim import EpisodeParams
from cr_sim.core.wander import WanderParams, WanderPolicy
import numpy as np

__all__ = ['RobotSideParams', 'ContactParams', 'Reading', 'Event', 'Step', 'RobotEpisodes',
           'START_MODES']

#: ``'wander'``: every episode starts where the wander policy leaves the robot (as in
#: ``clis run``); ``'here'``: the first one starts at once where the robot stands, the next
#: ones after the wander.
START_MODES = ('wander', 'here')


@frozen_dataclass(frozen=True)
class RobotSideParams:
    """What every node that is a robot's interface by its own sensors sets (the bridge's and
    the robot adapter's ``node`` sections of ``config/bridge.yaml``): episodes, the learner
    gate, frames."""

    start: str = param(choices=START_MODES, doc='where episodes start')
    first_episode: int = param(1, 2**31 - 1, doc='number of the first episode; > 1 goes on with '
                               'a run (clis run --resume: the episode after the checkpoint)')
    seed: int = param(0, 2**31 - 1, doc='seed of the wander steering noise')
    wait_for_learner: bool = param(doc='wander until learner/progress reports the last '
                                   'episode learned')
    learner_timeout: float = param(0.0, 3600.0, doc='wall seconds to wait for the learner')
    markers_period: float = param(0.01, 60.0, doc='robot marker period [s]')
    map_frame: str = param(doc='fixed frame of odom and markers')
    base_frame: str = param(doc='robot body frame')


@frozen_dataclass(frozen=True)
class ContactParams:
    """How the bridge detects a contact (``config/bridge.yaml`` section ``contact``)."""

    bump: bool = param(doc='the bump switch signals a contact')
    accel_threshold: float = param(0.0, 1000.0, doc='horizontal acceleration above this is a '
                                   'contact [m/s^2]; 0 = not used')
    ir_contact: float = param(0.0, 0.5, doc='an IR reading below this is a contact [m]; '
                              '0 = not used')


@dataclass(frozen=True)
class Reading:
    """One sensor frame in the bridge's clock.

    Attributes
    ----------
    t : float
        Bridge time [s] (device time, monotonic).
    ir : np.ndarray, shape (n_ir,)
    dest_bearing, dest_distance : float
        NaN when the destination is not seen / not ranged.
    landmark_bearings : np.ndarray, shape (n_landmarks,)
    wheels : np.ndarray, shape (2,)
    bump : int
    accel : tuple of float, shape (3,)
    dest_width : float
        The destination blob's apparent angular width [rad]; NaN when not seen or not measured
        (the Cyber Rodent's frames do not carry it).
    """

    t: float
    ir: np.ndarray
    dest_bearing: float
    dest_distance: float
    landmark_bearings: np.ndarray
    wheels: np.ndarray
    bump: int = 0
    accel: tuple[float, float, float] = (0.0, 0.0, 0.0)
    dest_width: float = math.nan

    def observation(self, t0: float) -> Observation:
        """The simulator's :class:`Observation` of this reading (time since ``t0``)."""
        return Observation(self.t - t0, self.ir, self.dest_bearing, self.landmark_bearings,
                           self.wheels)


@dataclass
class Step:
    """What one reading gives: events (in order), the reward of the frame (None outside an
    episode), and the wheel command of the wander policy (None: the controller drives).
    ``held``: the next episode is due but the learner has not reported the last one, and the
    caller holds the robot (:meth:`RobotEpisodes.step` with ``hold``): nothing else is given
    and the same reading is to be stepped again."""

    events: list[Event] = field(default_factory=list)
    reward: float | None = None
    wander: np.ndarray | None = None
    held: bool = False
    warning: str | None = None          # a gate's wait that timed out (to log)


class RobotEpisodes:
    """Episodes from sensor frames (module docstring).

    Parameters
    ----------
    episode : EpisodeParams
        Rewards, time limit, wander time (the simulator's).
    wander : WanderParams
        The wander policy's parameters (the simulator's).
    contact : ContactParams
    goal_radius : float
        The arena's destination radius [m].
    ir_angles : array_like, shape (n_ir,)
        Beam angles [rad] (for the wander policy).
    gate : EpisodeGate
        Its learner gate decides when the next episode may start (lockstep is not used: the
        robot's clock does not wait).
    rng : np.random.Generator
        The wander policy's steering noise.
    start : str
        One of :data:`START_MODES`.
    goal_width : float
        Above 0: the destination is reached when its blob looks at least this wide [rad]
        (:attr:`Reading.dest_width`), whatever its range; 0: when its range is within
        ``goal_radius``.
    first_episode : int
        The number of the first episode (> 1: a run that goes on from a checkpoint).
    """

    def __init__(self, episode: EpisodeParams, wander: WanderParams, contact: ContactParams,
                 goal_radius: float, ir_angles, gate: EpisodeGate, rng: np.random.Generator,
                 start: str = 'wander', *, goal_width: float = 0.0,
                 first_episode: int = 1) -> None:
        if start not in START_MODES:
            raise ValueError(f'start {start!r}: one of {", ".join(START_MODES)}')
        if not goal_width >= 0.0:
            raise ValueError(f'goal_width {goal_width!r}: must be >= 0')
        self.p = episode
        self.contact = contact
        self.goal_radius = goal_radius
        self.goal_width = goal_width
        self.gate = gate
        # numbering, events, return, learner gate
        self.book = EpisodeBook(gate, first_episode)
        self.policy = WanderPolicy(wander, ir_angles, rng)
        self.start_mode = start
        self.in_contact = False
        self.wander_since: float | None = None
        self._first = True

    @property
    def running(self) -> bool:
        """An episode runs (else the robot wanders to the next start)."""
        return self.book.running

    @property
    def episode(self) -> int:
        """The last episode started (0 before the first)."""
        return self.book.episode

    @property
    def ret(self) -> float:
        """The running (or last) episode's return."""
        return self.book.ret

    def is_contact(self, r: Reading) -> bool:
        c = self.contact
        if c.bump and r.bump:
            return True
        if c.accel_threshold > 0 and math.hypot(r.accel[0], r.accel[1]) > c.accel_threshold:
            return True
        return bool(c.ir_contact > 0 and r.ir.size and float(r.ir.min()) < c.ir_contact)

    def in_goal(self, r: Reading) -> bool:
        if math.isnan(r.dest_bearing):
            return False
        if self.goal_width > 0.0:
            return not math.isnan(r.dest_width) and r.dest_width >= self.goal_width
        return not math.isnan(r.dest_distance) and r.dest_distance <= self.goal_radius

    def step(self, r: Reading, now: float, hold: bool = False, ready: bool = True) -> Step:
        """One sensor frame at wall time ``now`` (wall time is for the learner gate only).
        ``hold``: a robot that waits for its controller (lockstep) waits at this frame for
        the learner, once the next episode is due, instead of wandering on while the learner
        learns (:attr:`Step.held`): the episode then starts where it would on any host.
        ``ready``: whether the graph's subscribers are matched (the first episode waits for
        them, :meth:`EpisodeGate.first`)."""
        out = Step()
        contact = self.is_contact(r)
        book = self.book
        if book.running:
            collision = contact and not self.in_contact
            reached = self.in_goal(r)
            timeout = not reached and r.t - book.t0 >= self.p.time_limit - 1e-6
            reward = (self.p.reward_collision if collision else 0.0) + \
                (self.p.reward_goal if reached else 0.0)
            book.add(reward)
            out.reward = reward
            self.in_contact = contact
            if reached or timeout:
                out.events.append(self._end('reached' if reached else 'timeout', r.t, now))
            return out
        self.in_contact = contact
        # between episodes: wander until the next start
        if self.wander_since is None:
            self.wander_since = r.t
            self.policy.reset()
            if self._first:
                self._first = False
                book.first(now, ready)
        if not book.ready:
            _, out.warning = book.poll(now, ready)
        here = self.start_mode == 'here' and book.episode == 0
        due = not self.in_goal(r) and (
            here or r.t - self.wander_since >= self.p.wander_time - 1e-6)
        if book.ready and due:
            self.wander_since = None
            out.events.append(book.start(r.t, start='here' if here else 'wander'))
            return out
        if hold and due:
            out.held = True                 # no draw of the wander policy: as on any host
            return out
        out.wander = self.policy.act(r.observation(self.wander_since))
        return out

    def _end(self, name: str, t: float, now: float) -> Event:
        ev = self.book.end(name, t, t - self.book.t0)
        self.wander_since = None
        self.book.release(now)
        return ev

    def end(self, t: float, now: float, reason: str = '') -> Event | None:
        """End the running episode from outside (``reset``: the service, or the link was
        lost); None if none runs."""
        if not self.book.running:
            return None
        ev = self._end('reset', t, now)
        if reason:
            ev.values['reason'] = reason
        return ev

    def end_by_service(self, t: float, now: float) -> tuple[Event | None, str]:
        """The ``reset`` service: :meth:`end` (reason ``service``), and the service's answer."""
        ev = self.end(t, now, 'service')
        return ev, (f'episode {self.episode} ended; the next starts after the wander' if ev
                    else 'no episode was running')
