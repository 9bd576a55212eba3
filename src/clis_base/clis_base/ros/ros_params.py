"""Declare a node's ROS parameters from a config file, and freeze them into dataclasses.

Every node of the project reads its defaults from a ``config/*.yaml`` ROS parameter file,
declares each (flattened, dotted) key as a ROS parameter with that default, so that
``--ros-args -p section.key:=value`` and ``--params-file`` override it, and then builds the
frozen parameter dataclass of its core from the values in force (validated: a bad value stops
the node with a message naming the key and the allowed range).

Overrides are checked here, once for every node (docs/design.md, parameters): a key that no
node of the project declares (a typo, ``node.sped_factor``) stops the node naming the nearest
known key; an integer for a float (``:=5``) is taken as that float; any other value of the
wrong type (``:=fast``) is declared as given, so that the node's dataclass rejects it naming
the key, the type and the range (:func:`clis_base.params.build`), instead of rclpy raising
from inside ``declare_parameter``. A key another node declares is left to that node: one
``--params-file`` (``/**``) serves the whole graph, as ``clis run --params`` gives it.
"""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING, Any

from clis_base.params import (
    flatten,
    is_ros_key,
    project_keys,
    unflatten,
    unknown_key,
)

if TYPE_CHECKING:                     # this module imports without rclpy (clis_learner's checks)
    from rclpy.node import Node

__all__ = ['declare_from_config', 'print_help_and_exit_if_asked']

def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _ros_value(value: Any) -> Any:
    """Lists of numbers are declared as float arrays so that overrides may be either."""
    if isinstance(value, (list, tuple)) and value and all(_is_number(v) for v in value):
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


def _coerce(default: Any, value: Any) -> tuple[Any, bool]:
    """``value`` (an override) in the type of ``default``: (value, True) when it has that type
    or an integer stands for a float (arrays too); (value, False) when it does not fit."""
    value = _plain(value)
    if isinstance(default, float):
        return (float(value), True) if _is_number(value) else (value, False)
    if isinstance(default, bool) or isinstance(value, bool):
        return value, type(value) is type(default)
    if isinstance(default, list):
        if not isinstance(value, list):
            return value, False
        if all(_is_number(v) for v in default) and all(_is_number(v) for v in value):
            return [float(v) for v in value], True
        if all(isinstance(v, str) for v in default) and all(isinstance(v, str) for v in value):
            return value, True
        return value, not value            # an empty array of any type
    return value, type(value) is type(default)


def declare_from_config(node: Node, defaults: dict) -> dict:
    """Declare every key of ``defaults`` (nested) as a parameter; return the values in force.

    Raises
    ------
    ConfigError
        An override that no node of the project declares, naming the nearest known key.
        (A value of the wrong type is returned as given, for the node's dataclass to reject
        with the key, the type and the range.)
    """
    from rcl_interfaces.msg import ParameterDescriptor

    from clis_base.ros.rclpy_private import parameter_overrides

    flat = flatten(defaults)
    overrides = parameter_overrides(node)
    known = project_keys() | set(flat)
    for key in sorted(overrides):
        if key not in known and not is_ros_key(key) and not node.has_parameter(key):
            raise unknown_key(key, flat if flat else known)
    values = {}
    for name, default in flat.items():
        default = _ros_value(default)
        if node.has_parameter(name):
            values[name] = _plain(node.get_parameter(name).value)
            continue
        if name not in overrides:
            node.declare_parameter(name, default)
            values[name] = _plain(node.get_parameter(name).value)
            continue
        value, fits = _coerce(default, overrides[name].value)
        if fits and value != []:          # the declared type stays the file's
            node.declare_parameter(name, value, ignore_override=True)
        else:                             # kept as given: the dataclass names key and range
            node.declare_parameter(name, value, ParameterDescriptor(dynamic_typing=True),
                                   ignore_override=True)
        values[name] = value
    return unflatten(values)


def print_help_and_exit_if_asked(doc: str | None, args: list[str] | None = None) -> None:
    """``--help`` before ``--ros-args``: print the node's docstring and how to set parameters."""
    argv = list(sys.argv[1:] if args is None else args)
    own = argv[:argv.index('--ros-args')] if '--ros-args' in argv else argv
    if '-h' in own or '--help' in own:
        print(f'usage: {sys.argv[0]} [--ros-args -p KEY:=VALUE ... --params-file FILE]\n')
        print((doc or '').strip())
        print('\nParameters: every key of the config file, dotted '
              '(e.g. -p node.speed_factor:=10.0).\nSee the README for the topic table.')
        raise SystemExit(0)
