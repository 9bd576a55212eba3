"""``ros2 run clis_learner learner``: trains every module from every episode (paper II-B..E).

Subscribes to the streams the paper's learning thread reads: every module's proposals
(``<module>/proposal``: its decision times and features ``b_i(x)``), the executed commands
(``arbiter/action``: who acted and its proposal), the arbiter's draws (``arbiter/selection``),
the rewards (``reward``, stamped at the end of the step that earned them) and the ``episode``
events. The records go into an :class:`~clis_learner.core.intake.EpisodeStream` (a
:class:`~clis_learner.core.memory.StreamBuffer`; ``clis learn`` feeds the same one from a bag)
in whatever order they arrive; when an episode ends (and all of its records have arrived: its
last reward, the arbiter's stop at its end, under sim time each module's last decision
``t_0 + l tau_i`` before the end; or ``learner_node.close_timeout`` s of wall time passed) the
buffer is cut into that episode's
memory and the same :class:`~clis_learner.core.learner.Learner` as the headless runner resamples
it to each module's grid and applies (7)-(9), (11).

After each learned episode, in this order: the episode's row is appended to
``OUT/episodes.csv``, the parameters are checkpointed atomically (``OUT/checkpoint.npz``, with
the simulator's ``resume_state`` of the episode's end: where ``clis run --resume`` goes on),
published on ``<module>/params`` (transient local, so a module that restarts gets them at once;
``version`` = episodes learned), and the row is published on ``~/progress``
(diagnostic_msgs/DiagnosticArray, transient local: episode, reached, return, who acted,
Pr(i|x_0), diagnostics; ``diverged`` names a module the divergence guard,
:mod:`~clis_learner.core.guard`, reports at this episode, which the log says too, once). An
episode whose start the learner did not see (it started late or was restarted), or that starts
once ``learner_node.episodes`` are learned, is not learned; its progress says so
(``learned: 0``). ``learner_node.resume`` starts from a checkpoint. The learner
reports ready (progress of episode 0, which a simulator with ``node.wait_for_learner``
waits for before the first episode) once DDS has found a publisher of every stream it
reads, or after ``learner_node.connect_timeout`` s.

Wakeups: the learner is off the sensor-to-command path, and a wakeup of its own at a decision
instant would take a core from the module or the arbiter that is on it. So the streams
(rewards, proposals, actions, draws) are not taken one by one: they wait in their queues
(:class:`~clis_base.ros.graph_node.OnDemand`) and are taken every 0.1 s of wall time, at each
episode event, and while an ended episode waits for its records (every 5 ms). The learner
reads no clock, so under sim time it takes ``/clock`` only on demand too (never). It is woken
by the episode events and its wall timer, not by the decisions nor at every tick.
"""

from __future__ import annotations

import csv
import math
import os
from pathlib import Path
import time

from clis_base.params import ConfigError, dataclass, param
from clis_base.ros.graph_node import GraphNode, OnDemand, run_node, take_all
from clis_base.trace import mark
from clis_modules.core.modules import arena_map, condition_periods, make_modules
from clis_modules.core.plugin import parse_condition
from clis_modules.module_node import END_EVENTS, LATCHED, PARAMS_QOS
from cr_sim.core.arena import load_arena
from cr_sim.core.sim import load_sim_params
from cr_sim.interface import unmatched
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Vector3Stamped
from rclpy.clock import Clock, ClockType
from rclpy.qos import QoSProfile
from sensor_msgs.msg import JointState

from clis_learner.core.agent_state import AgentState
from clis_learner.core.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from clis_learner.core.config import ClisParams, params_hash
from clis_learner.core.episodes import keep_rows_until
from clis_learner.core.intake import Closed, EpisodeStream
from clis_learner.intake_topics import feed_episode, feed_record, record_topics
from clis_modules import conversions as mconv
from cr_sim import conversions as rconv

__all__ = ['LearnerNodeParams', 'LearnerNode', 'PROGRESS_STATUS', 'main']

#: ``name`` of the learner's progress status.
PROGRESS_STATUS = 'learner'
PROGRESS_QOS = QoSProfile(depth=1, durability=LATCHED.durability)


@dataclass(frozen=True)
class LearnerNodeParams:
    """Settings of the learner node (``config/graph.yaml``, section ``learner_node``)."""

    out_dir: str = param(doc="folder for episodes.csv and checkpoint.npz; '' = none")
    resume: str = param(doc="checkpoint to start from; '' = the initial parameters")
    close_timeout: float = param(0.0, 600.0, doc='wall seconds to wait for the records of an '
                                  'ended episode')
    close_grace: float = param(0.0, 10.0, doc='wall seconds to wait for records in flight')
    connect_timeout: float = param(0.0, 3600.0, doc='wall seconds to wait for a publisher of '
                                   'every stream before reporting ready')
    episodes: int = param(0, 2**31 - 1, doc='learn until the parameters reach this version '
                          '(episodes learned in all), then learn no episode that starts '
                          'after; 0 = no limit')


class LearnerNode(GraphNode):
    """Thin glue around an :class:`~clis_learner.core.intake.EpisodeStream` (module docstring)."""

    control_path = False                    # learns between episodes: never real-time

    def __init__(self) -> None:
        super().__init__('learner', 'learner_node', LearnerNodeParams, clis_cls=ClisParams,
                         check_condition=parse_condition)
        self.modules = make_modules(self.clis, self.graph.condition,
                                    *arena_map(load_arena(self.graph.arena_file or None)))
        self.names = [m.name for m in self.modules]
        self.hash = params_hash(self.clis)
        version = 0
        meta: dict = {'extra': {}}
        if self.cfg.resume:
            try:
                meta = load_checkpoint(self.cfg.resume, self.modules, self.hash)
            except CheckpointError as exc:
                raise ConfigError(f'learner_node.resume: {exc}') from None
            version = int(meta['extra'].get('version', 0))
            self.get_logger().info(f'resumed from {self.cfg.resume}: version {version}')
        self.record_wall = -math.inf            # wall time the last record arrived
        self.resume_states: dict[int, str] = {}  # the simulator's, at each episode's end
        self._held_said = False
        self.stream = EpisodeStream(self.modules, self.clis, self.graph.condition,
                                    self.graph.seed, version)
        # the agent's random stream after each episode, for the next start to carry
        # (clis_learner.core.agent_state); a resumed run's from its checkpoint
        extra = meta['extra']
        taus = [tau for _, tau in condition_periods(self.clis, self.graph.condition)]
        self.agent = AgentState(
            self.graph.seed, taus, load_sim_params().episode.dt, self.clis.arbiter.selection,
            str(extra.get('agent_state', '')), int(extra.get('agent_after', 0)))
        if self.cfg.resume and 'agent_state' not in extra:
            self.agent.after = None              # a checkpoint without it: unknown
        self.out = Path(self.cfg.out_dir) if self.cfg.out_dir else None
        if self.out is not None:
            self.out.mkdir(parents=True, exist_ok=True)
            episode = meta['extra'].get('episode') if self.cfg.resume else None
            # a learner stopped between an episode's row and its checkpoint (killed, and
            # restarted by clis run): that row is learned again
            if episode is not None and (n := keep_rows_until(self.out / 'episodes.csv',
                                                             int(episode))):
                self.get_logger().info(f'{n} rows of episodes.csv after episode {episode} '
                                       'dropped (learned again)')

        self.pub_params = {name: self.create_publisher(JointState, f'{name}/params',
                                                       PARAMS_QOS) for name in self.names}
        self.pub_progress = self.create_publisher(DiagnosticArray, '~/progress', PROGRESS_QOS)
        # the streams wait in their queues (1000 deep: 50 s of sim time of rewards, 250 s of
        # the fastest module's decisions) until taken (module docstring)
        on_demand = OnDemand()

        def stream(msg_type, topic: str, callback):
            return self.create_subscription(msg_type, topic, callback, rconv.STREAM_DEPTH,
                                            callback_group=on_demand)
        # the record streams and their routing into the episode stream (intake_topics, as
        # clis learn reads a bag)
        callbacks = {'proposal': self._on_proposal, 'observation': self._on_observation,
                     'action': self._on_action,
                     'selection': self._on_selection, 'reward': self._on_reward}
        self.streams = [stream(msg_type, topic, callbacks[kind])
                        for kind, topic, msg_type in record_topics(self.names)]
        self.sub_episode = self.create_subscription(DiagnosticArray, 'episode',
                                                    self._on_episode, LATCHED)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(0.1, self._on_wall, clock=steady)
        # while an ended episode waits for its records
        self.closer = self.create_timer(0.005, self._on_wall, clock=steady)
        self.closer.cancel()
        self.clock_on_demand()
        self._publish_params(0.0)
        # "up": the simulator's learner gate starts the first episode on this report, so it
        # waits until DDS has found a publisher of every stream (a record published before
        # is never delivered, such as the arbiter's first draw)
        self.stream_topics = {sub.topic_name: 1 for sub in [*self.streams, self.sub_episode]}
        self.connect_deadline = time.monotonic() + self.cfg.connect_timeout
        self.connecting = self.create_timer(0.05, self._on_connecting, clock=steady)
        self._on_connecting()
        self.defer_housekeeping()
        self.get_logger().info(
            f'learner: condition {self.graph.condition}, modules {", ".join(self.names)}, '
            f'correction {self.clis.learner.correction}, out {self.out or "-"}')

    def _on_connecting(self) -> None:
        """Report ready once every stream has a publisher (or ``connect_timeout`` passed)."""
        missing = unmatched(self, self.stream_topics)
        if missing and time.monotonic() < self.connect_deadline:
            return
        if missing:
            self.get_logger().warning(
                f'no publisher within {self.cfg.connect_timeout} s of: {", ".join(missing)}: '
                'ready anyway')
        self.connecting.cancel()
        self._progress({'episode': 0, 'learned': 0, 'event': 'ready'}, 0.0)

    @property
    def version(self) -> int:
        """Episodes learned (the parameters' version)."""
        return self.stream.version

    # ------------------------------------------------------------------ streams

    def _take_streams(self) -> None:
        """Take the records waiting in the streams' queues (any order: the stream sorts)."""
        for sub in self.streams:
            for msg in take_all(sub):
                sub.callback(msg)

    def _on_proposal(self, msg: JointState) -> None:
        self.record_wall = time.monotonic()
        try:
            feed_record(self.stream, 'proposal', msg)
        except (ValueError, KeyError) as exc:
            self.get_logger().error(f'ignored proposal: {exc}')

    def _on_observation(self, msg: JointState) -> None:
        self.record_wall = time.monotonic()
        try:
            feed_record(self.stream, 'observation', msg)
        except (ValueError, KeyError) as exc:
            self.get_logger().error(f'ignored observation: {exc}')

    def _on_action(self, msg: JointState) -> None:
        self.record_wall = time.monotonic()
        try:
            feed_record(self.stream, 'action', msg)
        except KeyError as exc:
            self.get_logger().error(
                f'ignored an action of {exc.args[0]!r}, not a module of condition '
                f'{self.graph.condition} (another graph on this ROS_DOMAIN_ID?)',
                throttle_duration_sec=5.0)

    def _on_selection(self, msg: JointState) -> None:
        feed_record(self.stream, 'selection', msg)

    def _on_reward(self, msg: Vector3Stamped) -> None:
        self.record_wall = time.monotonic()
        feed_record(self.stream, 'reward', msg)

    def _on_episode(self, msg: DiagnosticArray) -> None:
        self._take_streams()
        now = time.monotonic()
        ev = feed_episode(self.stream, msg, now + self.cfg.close_timeout,
                          now + self.cfg.close_grace)
        if ev.event == 'start':
            self.agent.start(ev.index, ev.t,
                             float(ev.values.get('dt', self.agent.stream.clock.dt)))
            if ev.closed is not None:
                self._closed(ev.closed)
            if self.cfg.episodes and self.version >= self.cfg.episodes:
                self.stream.episode = None        # the run has learned its episodes
        elif ev.event in END_EVENTS:
            self.agent.end(ev.index, ev.t)
            if 'resume_state' in ev.values:
                self.resume_states[ev.index] = ev.values['resume_state']
            if ev.skipped is not None:            # its start was not seen: nothing to learn
                self._progress(ev.skipped, ev.t)
            elif self.stream.closing is not None:
                self.closer.reset()               # wait for its records

    def _on_wall(self) -> None:
        self._take_streams()
        c = self.stream.closing
        if c is None:
            self.closer.cancel()
            return
        # the timeout counts from the last record that arrived: a learner working through a
        # backlog (a loaded machine) does not give up early
        c['deadline'] = max(c['deadline'], self.record_wall + self.cfg.close_timeout)
        close, missing = self.stream.due(time.monotonic(), on_grid=self.sim_time)
        if not close:
            return
        if missing:
            self.get_logger().warning(
                f'episode {self.stream.episode["index"]}: {", ".join(missing)} did not arrive '
                f'within {self.cfg.close_timeout} s: learning from what did')
        mark('learner_learn0')
        self._closed(self.stream.close())
        self.closer.cancel()

    # ------------------------------------------------------------------ learning

    def _closed(self, closed: Closed) -> None:
        """After an episode: checkpoint, parameters, CSV row, progress (module docstring)."""
        mark('learner_closed0', closed.t_end)
        # (an episode not learned, e.g. one a restarted learner sees in the ``episode`` topic's
        # history, without its rewards, is not a loss to report)
        if closed.learned and not closed.row['complete']:
            self.get_logger().warning(
                f'episode {closed.episode}: the rewards received sum to '
                f'{closed.row["ret"]:.3f}, the simulator says {closed.sim_return:.3f}: reward '
                'messages were lost (learning from it anyway; `complete` = 0 in episodes.csv)')
        if closed.row.get('held_steps') and not self._held_said:
            self._held_said = True
            self.get_logger().warning(
                f'episode {closed.episode}: {closed.row["held_steps"]} off-policy steps scored '
                "the behaviour's density at its latest decision, not at the learner's instant "
                '(learner.behaviour_state = resampled needs observations that the module nodes '
                'do not publish yet; column held_steps of episodes.csv)')
        for d in closed.diverged:            # the divergence guard: once per module
            self.get_logger().error(d.message())
        if closed.learned:
            if self.out is not None:
                # the row first: stopped between the two, the checkpoint is the episode before
                # and `clis run --resume` drops the row and runs the episode again (the other
                # way round the row would be lost)
                self._append_csv(closed.row)
                # and where the simulator stood: a resumed run goes on from there
                # (clis_app.graph.run)
                sim = self.resume_states.get(closed.episode)
                save_checkpoint(self.out / 'checkpoint.npz', self.modules, self.hash,
                                {'version': self.version, 'episode': closed.episode,
                                 'condition': self.graph.condition, 'seed': self.graph.seed,
                                 **({'sim_state': sim} if sim else {}),
                                 **self._agent_after(closed.episode)})
            self.resume_states = {k: v for k, v in self.resume_states.items()
                                  if k > closed.episode}
            self._publish_params(closed.t_end)
        self._progress(closed.row, closed.t_end)
        mark('learner_closed1', closed.t_end)

    def _publish_params(self, t: float) -> None:
        for m in self.modules:
            self.pub_params[m.name].publish(mconv.params_msg(m.name, m.w, m.W, m.sigma,
                                                             self.version, t))

    def _agent_after(self, episode: int) -> dict:
        """The agent stream's state after ``episode`` (if that is where it stands)."""
        said = self.agent.announcement()
        return said if said.get('agent_after') == episode else {}

    def _progress(self, row: dict, t: float) -> None:
        row = {'version': self.version, **row, **self.agent.announcement()}
        self.pub_progress.publish(rconv.event_msg(
            PROGRESS_STATUS, 'learned' if row.get('learned') else 'skipped', t, **row))

    def _append_csv(self, row: dict) -> None:
        path = self.out / 'episodes.csv'
        new = not path.is_file() or path.stat().st_size == 0
        fields = list(row)
        if not new:                                  # resumed: keep the file's columns
            with open(path, newline='') as fh:
                fields = next(csv.reader(fh), fields)
        with open(path, 'a', newline='') as fh:
            writer = csv.DictWriter(fh, fieldnames=fields, extrasaction='ignore')
            if new:
                writer.writeheader()
            writer.writerow(row)
            fh.flush()
            os.fsync(fh.fileno())


def main(args: list[str] | None = None) -> None:
    run_node(LearnerNode, 'learner', __doc__, args)


if __name__ == '__main__':
    main()
