"""A Ctrl-C remembered for the whole of one ``clis`` command.

Python turns SIGINT into a ``KeyboardInterrupt`` raised wherever the main thread is. Raised
inside a gc callback or a ``__del__`` it is swallowed ("Exception ignored in ..."), and a run
that was asked to stop goes on to its end (seen: a Ctrl-C while ``clis run`` imported its
modules, the run then learned all its episodes and exited 0). So ``clis`` installs this handler
first: it raises as Python's does, and remembers. What runs for long (``clis run``'s wall timer,
its supervisor) checks :func:`interrupted` too, so a swallowed Ctrl-C still stops it.
"""

from __future__ import annotations

import signal
import threading
from typing import Any

__all__ = ['handler', 'install', 'interrupted', 'remember']

_signals: list[int] = []


def remember(signum: int) -> None:
    """Remember a SIGINT (or SIGTERM) without raising."""
    _signals.append(signum)


def handler(signum: int, frame: Any) -> None:
    """SIGINT: remembered, then ``KeyboardInterrupt`` as Python's default handler raises."""
    remember(signum)
    raise KeyboardInterrupt


def install() -> Any:
    """Forget earlier Ctrl-Cs and install :func:`handler` (from the main thread only; else
    nothing is installed). Returns the handler it replaced, to restore (or None)."""
    _signals.clear()
    if threading.current_thread() is not threading.main_thread():
        return None
    return signal.signal(signal.SIGINT, handler)


def interrupted() -> bool:
    """Whether a Ctrl-C came since :func:`install` (even one whose exception was lost)."""
    return bool(_signals)
