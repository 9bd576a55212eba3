"""Declare a node's ROS parameters from a config file, and freeze them into dataclasses.

Every node of the project reads its defaults from a ``config/*.yaml`` ROS parameter file,
declares each (flattened, dotted) key as a ROS parameter with that default, so that
``--ros-args -p section.key:=value`` and ``--params-file`` override it, and then builds the
frozen parameter dataclass of its core from the values in force (validated: a bad value stops
the node with a message naming the key and the allowed range).
"""

from __future__ import annotations

import sys
from typing import Any

from rclpy.node import Node

from cr_sim.core.params import flatten, unflatten


def _ros_value(value: Any) -> Any:
    """Lists of numbers are declared as float arrays so that overrides may be either."""
    if isinstance(value, (list, tuple)) and value and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
        return [float(v) for v in value]
    return value


def _plain(value: Any) -> Any:
    """ROS array types (array.array / numpy) back to plain lists."""
    if value is not None and not isinstance(value, (str, bytes, bool, int, float, list)):
        try:
            return list(value)
        except TypeError:
            return value
    return value


def declare_from_config(node: Node, defaults: dict) -> dict:
    """Declare every key of ``defaults`` (nested) as a parameter; return the values in force."""
    flat = flatten(defaults)
    for name, value in flat.items():
        if not node.has_parameter(name):
            node.declare_parameter(name, _ros_value(value))
    return unflatten({name: _plain(node.get_parameter(name).value) for name in flat})


def print_help_and_exit_if_asked(doc: str | None, args: list[str] | None = None) -> None:
    """``--help`` before ``--ros-args``: print the node's docstring and how to set parameters."""
    argv = list(sys.argv[1:] if args is None else args)
    own = argv[:argv.index('--ros-args')] if '--ros-args' in argv else argv
    if '-h' in own or '--help' in own:
        print(f'usage: {sys.argv[0]} [--ros-args -p KEY:=VALUE ... --params-file FILE]\n')
        print((doc or '').strip())
        print('\nParameters: every key of the config file, dotted '
              '(e.g. -p node.speed_factor:=10.0).\nThe topic table: docs/robot.md.')
        raise SystemExit(0)
