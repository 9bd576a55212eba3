"""A node process's life: its heap settled before it spins, and a clean stop told from a crash.

Before spinning, a node moves the objects alive then (rclpy, numpy, numba and their modules,
the node itself: ~75,000 objects) out of the garbage collector's reach (:func:`settle_heap`):
a full collection otherwise walks them all, a pause of 0.1-0.5 s measured in a graph node,
which lands on the decision path whenever it comes. Objects made later are collected as usual.

Ctrl-C or SIGTERM shuts the rclpy context down from a signal handler, possibly while the
executor is building its wait set or taking a message. rclpy then raises from inside the
executor: ``RCLError`` ('failed to initialize wait set: the given context is not valid') or a
pybind11 ``RuntimeError`` ('Unable to convert call argument ... to Python object', seen in the
simulator's log at the end of a ``clis run``). After a shutdown either is a clean stop; while
the context is still valid it is a real error.
"""

from __future__ import annotations

import gc

import rclpy
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

__all__ = ['SHUTDOWN_RACES', 'RCLError', 'reraise_unless_shut_down', 'settle_heap']

RCLError = _rclpy.RCLError
#: What the executor may raise when the context is shut down under it.
SHUTDOWN_RACES = (RCLError, RuntimeError)


def reraise_unless_shut_down() -> None:
    """Inside an ``except SHUTDOWN_RACES:`` block: re-raise unless rclpy was shut down."""
    if rclpy.ok():
        raise


def settle_heap() -> None:
    """Collect the garbage of the start-up, then freeze what is alive (module docstring): the
    collector's later passes skip it (``gc.freeze``, Python >= 3.7)."""
    gc.collect()
    gc.freeze()
