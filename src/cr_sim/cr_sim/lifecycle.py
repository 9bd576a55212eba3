"""How a node process tells a clean stop from a crash.

Ctrl-C or SIGTERM shuts the rclpy context down from a signal handler, possibly while the
executor is building its wait set or taking a message. rclpy then raises from inside the
executor: ``RCLError`` ('failed to initialize wait set: the given context is not valid') or a
pybind11 ``RuntimeError`` ('Unable to convert call argument ... to Python object', seen in the
simulator's log at the end of a ``clis run``). After a shutdown either is a clean stop; while
the context is still valid it is a real error.
"""

from __future__ import annotations

import rclpy
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

__all__ = ['SHUTDOWN_RACES', 'RCLError', 'reraise_unless_shut_down']

RCLError = _rclpy.RCLError
#: What the executor may raise when the context is shut down under it.
SHUTDOWN_RACES = (RCLError, RuntimeError)


def reraise_unless_shut_down() -> None:
    """Inside an ``except SHUTDOWN_RACES:`` block: re-raise unless rclpy was shut down."""
    if rclpy.ok():
        raise
