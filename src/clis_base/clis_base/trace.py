"""``CLIS_TRACE=DIR``: timestamps along the sensor-to-command path (a development aid).

Every node of the graph marks the steps of a decision instant with :func:`mark` (the
simulator's publication of the readings, a module's wakeup, decision and proposal, the
arbiter's receipt and its ``cmd_vel``, the simulator's receipt; garbage collections and the
learner's updates too). With ``CLIS_TRACE`` set the marks are kept in memory and written at the
node's exit to ``DIR/NAME-PID.trace``, one ``wall_ns event sim_t`` line each (``wall_ns`` is
``CLOCK_MONOTONIC``, one clock for every process of the machine); unset, :func:`mark` returns at
once. ``bench/trace_round_trip.py DIR`` breaks the round trip of every held instant down.
"""

from __future__ import annotations

import gc
import os
from pathlib import Path
import time

__all__ = ['TRACING', 'mark', 'dump']

#: Whether ``CLIS_TRACE`` is set (callers may skip building a mark's arguments).
TRACING = bool(os.environ.get('CLIS_TRACE'))
_marks: list[tuple[int, str, float]] = []
_gc_start = [0]


def mark(event: str, t: float = float('nan')) -> None:
    """Record ``event`` at sim time ``t`` now (no-op unless ``CLIS_TRACE`` is set)."""
    if TRACING:
        _marks.append((time.monotonic_ns(), event, t))


def _on_gc(phase: str, info: dict) -> None:
    if phase == 'start':
        _gc_start[0] = time.monotonic_ns()
    else:
        _marks.append((_gc_start[0], f'gc{info["generation"]}_start', float('nan')))
        _marks.append((time.monotonic_ns(), f'gc{info["generation"]}_end', float('nan')))


if TRACING:
    gc.callbacks.append(_on_gc)


def dump(name: str) -> None:
    """Write the marks so far to ``$CLIS_TRACE/NAME-PID.trace`` and forget them."""
    if not TRACING or not _marks:
        return
    out = Path(os.environ['CLIS_TRACE'])
    out.mkdir(parents=True, exist_ok=True)
    with open(out / f'{name}-{os.getpid()}.trace', 'a') as fh:
        fh.writelines(f'{w} {e} {t!r}\n' for w, e, t in _marks)
    _marks.clear()
