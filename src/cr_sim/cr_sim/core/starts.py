"""Where an episode starts: one rule shared by the headless runner and the sim node."""

from __future__ import annotations

import math

import numpy as np

from cr_sim.core.arena import Arena

#: ``'starts'``: one of the arena's named starts (A-E) drawn uniformly, with a uniform heading;
#: a start name: that start with the file's heading; ``'random'``: a random free pose;
#: ``'wander'``: where the hand-made wander policy leaves the robot (as on the real CR).
START_MODES = ('starts', 'random', 'wander')


def draw_start(mode: str, arena: Arena, rng: np.random.Generator) -> tuple[str, float | None]:
    """The ``(start, heading)`` arguments of :meth:`Simulator.reset` for a start ``mode``.

    Parameters
    ----------
    mode : str
        One of :data:`START_MODES` or a start name of the arena.
    rng : np.random.Generator
        Draws the start and heading for ``'starts'`` (independent of the simulator's own).
    """
    if mode == 'starts':
        names = arena.start_names
        return names[int(rng.integers(len(names)))], float(rng.uniform(-math.pi, math.pi))
    if mode in ('random', 'wander') or mode in arena.start_names:
        return mode, None
    raise ValueError(f'unknown start {mode!r}: one of {", ".join(arena.start_names)} or '
                     + ', '.join(repr(m) for m in START_MODES))
