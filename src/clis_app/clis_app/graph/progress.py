"""What ``clis run`` follows while the graph runs: the learner's progress, in one line.

:class:`Monitor` is the rclpy node of ``clis run`` itself (``clis_run``): it collects the
learner's progress rows (``learner/progress``) and tells which nodes are up;
:class:`ProgressView` shows the newest row as one line and says when the run is done.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
import sys
import time

from clis_learner.core.guard import Divergence

__all__ = ['Monitor', 'ProgressView']


class Monitor:
    """An rclpy node of ``clis run``: the learner's progress and the graph's discovery."""

    def __init__(self, namespace: str = '') -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        import rclpy
        from rclpy.qos import DurabilityPolicy, QoSProfile

        from cr_sim import conversions as rconv
        self.rconv = rconv
        self.node = rclpy.create_node('clis_run', namespace=namespace or None)
        self.rows: list[dict[str, str]] = []
        self.node.create_subscription(
            DiagnosticArray, 'learner/progress', self._on_progress,
            QoSProfile(depth=10, durability=DurabilityPolicy.TRANSIENT_LOCAL))

    def _on_progress(self, msg) -> None:
        t, event, values = self.rconv.event_from_msg(msg)
        if values.get('event') == 'ready':             # the learner is up
            return
        values['t_end'] = values.get('t_end', str(t))
        if self.rows and self.rows[-1].get('episode') == values.get('episode') \
                and self.rows[-1].get('version') == values.get('version'):
            return                                     # the latched copy of one seen
        self.rows.append(values)

    def up(self, nodes: list[str]) -> list[str]:
        """Which of ``nodes`` are not up yet: not discovered, or without their ``episode``
        subscription (created last but one by each graph node, after its other inputs)."""
        seen = dict(self.node.get_node_names_and_namespaces())
        missing = []
        for n in nodes:
            try:
                topics = ([t for t, _ in self.node.get_subscriber_names_and_types_by_node(
                    n, seen[n])] if n in seen else [])
            except Exception:                           # noqa: BLE001 vanished meanwhile
                topics = []
            if not any(t.rsplit('/', 1)[-1] == 'episode' for t in topics):
                missing.append(n)
        return missing

    def spin(self, timeout: float) -> None:
        import rclpy
        rclpy.spin_once(self.node, timeout_sec=timeout)


class ProgressView:
    """The one-line progress of a run, from the learner's progress rows.

    ``table``: the run's ``episodes.csv``, where the learner appends each learned episode's row
    before it publishes the progress. The run is done when either says ``target`` episodes
    were learned since the view was made: a progress row published before ``clis run``'s
    subscription was matched with the learner's publisher is not delivered to it (transient
    local keeps the newest only), and a short run's episodes can all be learned in that
    moment.
    """

    def __init__(self, target: int, block: int, quiet: bool, tty: bool,
                 time_limit: float = 0.0, table: Path | None = None) -> None:
        self.target, self.block, self.quiet, self.tty = target, block, quiet, tty
        self.time_limit = time_limit * 60.0
        self.t_start = time.monotonic()
        self.shown = 0
        self.learned = 0
        self.table = table
        self._table_size = -1
        self._table_rows = self.table_rows0 = self._count_rows()
        #: what the divergence guard reported so far
        self.diverged: list[Divergence] = []

    def _count_rows(self) -> int:
        """Rows of :attr:`table` (0 without one), counted again only when its size changed."""
        if self.table is None:
            return 0
        try:
            size = self.table.stat().st_size
        except OSError:
            return 0
        if size != self._table_size:
            self._table_size = size
            with open(self.table, newline='') as fh:
                self._table_rows = max(0, sum(1 for _ in csv.reader(fh)) - 1)
        return self._table_rows

    @property
    def table_learned(self) -> int:
        """Episodes the learner appended to :attr:`table` since the view was made and
        checkpointed (``checkpoint.npz`` beside it written after the table's last row: the
        learner writes the row, then the checkpoint, then publishes the progress)."""
        n = self._count_rows() - self.table_rows0
        if n <= 0:
            return 0
        try:
            done = (self.table.with_name('checkpoint.npz').stat().st_mtime_ns
                    >= self.table.stat().st_mtime_ns)
        except OSError:
            done = False
        return n if done else n - 1

    @property
    def out_of_time(self) -> bool:
        return self.time_limit > 0 and time.monotonic() - self.t_start >= self.time_limit

    def update(self, rows: list[dict[str, str]]) -> bool:
        """Show the newest row; True once ``target`` episodes are learned (or the time limit
        is reached)."""
        if len(rows) <= self.shown:
            return self.out_of_time or self.table_learned >= self.target
        new, self.shown = rows[self.shown:], len(rows)
        done = [r for r in rows if r.get('learned') == '1']
        self.learned = len(done)
        for r in new:
            # the divergence guard (clis_learner.core.guard): a line of its own, even --quiet
            for d in Divergence.from_row(r, int(float(r.get('version', 0) or 0))):
                self.diverged.append(d)
                print(('\r\033[K' if self.tty else '') + f'WARNING: {d.message()}',
                      file=sys.stderr, flush=True)
        if not self.quiet:
            line = self.line(rows[-1], done, time.monotonic() - self.t_start)
            print(('\r\033[K' + line[:200]) if self.tty else line, end='' if self.tty else '\n',
                  file=sys.stderr, flush=True)
        return (max(self.learned, self.table_learned) >= self.target
                or self.out_of_time)

    def line(self, last: dict[str, str], done: list[dict[str, str]], wall: float) -> str:
        recent = done[-self.block:]
        succ = sum(int(float(r.get('reached', 0))) for r in recent)
        probs = ' '.join(f'{k[2:]}={float(v):.2f}' for k, v in last.items()
                         if k.startswith('p_') and v not in ('nan', ''))
        # sim time starts at 0 with the simulator
        rtf = float(last.get('t_end', 'nan')) / wall if wall > 0 else math.nan
        eta = wall * (self.target - self.learned) / self.learned if self.learned else math.nan
        what = 'reached' if last.get('reached') == '1' else last.get('event', '?')
        gone = ''.join(f' | {d.module} DIVERGED at {d.episode}' for d in self.diverged)
        return (f'episode {self.learned}/{self.target}{gone} | {succ}/{len(recent)} reached in '
                f'the last {len(recent)} | ep {last.get("episode")}: {what} '
                f'{float(last.get("duration", "nan")):.1f} s, acted {last.get("behaviour", "-")}'
                f'{" | P(i|x0) " + probs if probs else ""} | x{rtf:.0f} real time | '
                f'{wall / 60:.1f} min, ETA {eta / 60:.1f} min')

    def summary(self) -> str:
        return (f'{self.learned} episodes learned in '
                f'{(time.monotonic() - self.t_start) / 60:.1f} min')
