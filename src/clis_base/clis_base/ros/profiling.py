"""``CLIS_PROFILE=DIR``: profile a node's spinning with :mod:`cProfile` (a development aid).

Every node's ``main`` (the simulator, the CLIS graph nodes) calls :func:`start_profile` before
it spins and :func:`stop_profile` when it stops; with ``CLIS_PROFILE`` set the statistics go to
``DIR/NAME.prof`` (``python -m pstats DIR/NAME.prof``). cProfile slows Python code down several
times: read the shares of the work, not the speed.
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ['start_profile', 'stop_profile']


def start_profile():
    """A running :class:`cProfile.Profile` with ``CLIS_PROFILE`` set, else None."""
    if not os.environ.get('CLIS_PROFILE'):
        return None
    import cProfile
    profiler = cProfile.Profile()
    profiler.enable()
    return profiler


def stop_profile(profiler, name: str) -> None:
    """Write ``profiler``'s statistics (if any) to ``$CLIS_PROFILE/NAME.prof``."""
    if profiler is None:
        return
    profiler.disable()
    out = Path(os.environ['CLIS_PROFILE'])
    out.mkdir(parents=True, exist_ok=True)
    profiler.dump_stats(str(out / f'{name}.prof'))
