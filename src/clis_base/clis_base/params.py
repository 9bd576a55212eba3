"""Frozen parameter dataclasses whose defaults live in ``config/`` files.

Every tunable of the project is declared once, as a field of a frozen dataclass with its type
and its allowed range (``param(lo, hi)`` or ``param(choices=...)``). Values come from the
ROS 2 parameter files in ``config/`` (``node: ros__parameters: ...``), so that the headless
runner and the ROS nodes read the same numbers. A bad value is rejected at load time with a
message that names the file, the key and the allowed range.

Example
-------
>>> @dataclass(frozen=True)
... class Foo:
...     alpha: float = param(0.0, 1.0, doc="step size")
>>> build(Foo, {"alpha": 0.1}, where="foo").alpha
0.1
"""

from __future__ import annotations

from collections.abc import Mapping
import copy
import dataclasses
from dataclasses import MISSING, dataclass, field
import difflib
import functools
import math
import os
from pathlib import Path
import typing
from typing import Any

import yaml

__all__ = [
    'ConfigError', 'param', 'build', 'build_fields', 'load_yaml', 'ros_parameters', 'config_dir',
    'replace',
    'dataclass', 'as_dict', 'identity_dict', 'set_dotted', 'flatten', 'unflatten', 'load_params',
    'ROS_KEYS', 'project_keys', 'is_ros_key', 'unknown_key',
]


class ConfigError(ValueError):
    """A configuration value is missing, unknown, of the wrong type or out of range."""


def param(lo: float | None = None, hi: float | None = None, *, choices: tuple | None = None,
          doc: str = '', off: Any = None) -> Any:
    """Declare a parameter field: required (no code default), with its allowed range.

    Parameters
    ----------
    lo, hi : float, optional
        Inclusive bounds for numbers (for sequences: for every element).
    choices : tuple, optional
        Allowed values (for strings).
    doc : str
        One line shown in error messages and ``--help``.
    off : optional
        For an option added after runs were saved: the value at which it changes nothing.
        :func:`identity_dict` leaves the field out at that value, so a configuration that
        does not use the option keeps the identity (the parameter hash of saved runs and
        checkpoints) it had before the option existed.
    """
    return field(metadata={'lo': lo, 'hi': hi, 'choices': choices, 'doc': doc, 'off': off})


def _describe(meta: Mapping[str, Any]) -> str:
    if meta.get('choices') is not None:
        return 'one of ' + ', '.join(repr(c) for c in meta['choices'])
    lo, hi = meta.get('lo'), meta.get('hi')
    if lo is None and hi is None:
        return 'any value of the declared type'
    return f'in [{lo if lo is not None else "-inf"}, {hi if hi is not None else "inf"}]'


def _check_number(value: Any, where: str, meta: Mapping[str, Any], integer: bool) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f'{where} = {value!r} must be a number, {_describe(meta)}')
    if integer and float(value) != int(value):
        raise ConfigError(f'{where} = {value!r} must be an integer, {_describe(meta)}')
    if not math.isfinite(float(value)):
        raise ConfigError(f'{where} = {value!r} must be finite, {_describe(meta)}')
    lo, hi = meta.get('lo'), meta.get('hi')
    if (lo is not None and value < lo) or (hi is not None and value > hi):
        raise ConfigError(f'{where} = {value!r} is out of range: must be {_describe(meta)}')
    return int(value) if integer else float(value)


def _convert(tp: Any, value: Any, where: str, meta: Mapping[str, Any]) -> Any:
    origin = typing.get_origin(tp)
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, Mapping):
            raise ConfigError(f'{where} must be a mapping of the fields of {tp.__name__}')
        return build(tp, value, where=where)
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f'{where} = {value!r} must be true or false')
        return value
    if tp is int:
        return _check_number(value, where, meta, integer=True)
    if tp is float:
        return _check_number(value, where, meta, integer=False)
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f'{where} = {value!r} must be a string, {_describe(meta)}')
        if meta.get('choices') is not None and value not in meta['choices']:
            raise ConfigError(f'{where} = {value!r} is not allowed: must be {_describe(meta)}')
        return value
    if origin is tuple:
        args = typing.get_args(tp)
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f'{where} = {value!r} must be a list')
        if len(args) == 2 and args[1] is Ellipsis:
            elem_types = [args[0]] * len(value)
        else:
            if len(value) != len(args):
                raise ConfigError(f'{where} = {value!r} must have {len(args)} elements')
            elem_types = list(args)
        return tuple(_convert(t, v, f'{where}[{k}]', meta)
                     for k, (t, v) in enumerate(zip(elem_types, value)))
    if origin is typing.Union or str(origin) == "<class 'types.UnionType'>":
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if value is None:
            return None
        return _convert(args[0], value, where, meta)
    return value


def build(cls: type, mapping: Mapping[str, Any], where: str = '') -> Any:
    """Construct the frozen dataclass ``cls`` from ``mapping``, validating every field.

    A class with a ``__build_params__(mapping, where)`` classmethod builds itself (sections
    whose names are not fields, such as the module instances of ``clis.yaml``); it calls
    :func:`build_fields` for its own fields.

    Raises
    ------
    ConfigError
        Naming ``where.key`` for a missing key, an unknown key (with the allowed keys) or a
        value outside its declared range.
    """
    custom = getattr(cls, '__build_params__', None)
    if custom is not None:
        return custom(mapping, where)
    return build_fields(cls, mapping, where)


def build_fields(cls: type, mapping: Mapping[str, Any], where: str = '') -> Any:
    """:func:`build` of ``cls``'s own fields (no ``__build_params__``)."""
    if not isinstance(mapping, Mapping):
        raise ConfigError(f'{where or cls.__name__} must be a mapping')
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    prefix = f'{where}.' if where else ''
    unknown = sorted(set(mapping) - set(fields))
    if unknown:
        raise ConfigError(f'unknown key {prefix}{unknown[0]}; allowed keys: '
                          + ', '.join(sorted(fields)))
    kwargs = {}
    for name, f in fields.items():
        if name not in mapping:
            if f.default is not MISSING or f.default_factory is not MISSING:
                continue
            raise ConfigError(f'missing key {prefix}{name} ({f.metadata.get("doc", "")}; '
                              f'{_describe(f.metadata)})')
        kwargs[name] = _convert(hints[name], mapping[name], prefix + name, f.metadata)
    obj = cls(**kwargs)
    check = getattr(obj, 'validate', None)
    if callable(check):
        try:
            check()
        except ConfigError:
            raise
        except ValueError as exc:
            raise ConfigError(f'{where or cls.__name__}: {exc}') from exc
    return obj


def as_dict(obj: Any, drop_off: bool = False) -> dict:
    """Plain nested dict of a parameter dataclass (tuples become lists), for YAML/JSON;
    ``drop_off``: without the fields at their declared ``off`` value (:func:`param`)."""
    def kept(v: Any, f: dataclasses.Field) -> bool:
        off = f.metadata.get('off')
        return not drop_off or off is None or getattr(v, f.name) != off

    def conv(v: Any) -> Any:
        if dataclasses.is_dataclass(v):
            return {f.name: conv(getattr(v, f.name)) for f in dataclasses.fields(v)
                    if kept(v, f)}
        if isinstance(v, (tuple, list)):
            return [conv(x) for x in v]
        return v
    return conv(obj)


def identity_dict(obj: Any) -> dict:
    """What identifies a configuration: :func:`as_dict` without the fields at their declared
    ``off`` value."""
    return as_dict(obj, drop_off=True)


def replace(obj: Any, **changes: Any) -> Any:
    """``dataclasses.replace`` that re-validates through :func:`build`."""
    d = as_dict(obj)
    d.update(changes)
    return build(type(obj), d)


def set_dotted(mapping: dict, dotted: str, value: Any) -> None:
    """Set ``mapping['a']['b'] = value`` for ``dotted = 'a.b'``; the path must exist."""
    keys = dotted.split('.')
    node = mapping
    for k in keys[:-1]:
        if not isinstance(node, dict) or k not in node:
            raise ConfigError(f'unknown key {dotted} (no section {k!r})')
        node = node[k]
    if keys[-1] not in node:
        raise ConfigError(f'unknown key {dotted}; allowed keys here: ' + ', '.join(sorted(node)))
    node[keys[-1]] = value


def config_dir() -> Path:
    """The folder holding the default config files.

    ``$CLIS_CONFIG_DIR`` if set, else the repository's ``config/`` (when run from source),
    else the installed ``share/clis_base/config``.
    """
    env = os.environ.get('CLIS_CONFIG_DIR')
    if env:
        return Path(env)
    here = Path(__file__).resolve()
    for parent in here.parents:
        if (parent / 'config' / 'arena.yaml').is_file() and (parent / 'src').is_dir():
            return parent / 'config'
    try:
        from ament_index_python.packages import get_package_share_directory
        return Path(get_package_share_directory('clis_base')) / 'config'
    except Exception:  # noqa: BLE001 - not installed: fall through to a clear error
        pass
    raise ConfigError('cannot find the config folder: set CLIS_CONFIG_DIR')


#: Parsed YAML files by (path, modification time, size): an experiment reads the same three
#: files for every run it validates and starts (yaml's pure-Python parser, ~10 ms a file).
_YAML_CACHE: dict[tuple[str, int, int], dict] = {}


def load_yaml(path: str | os.PathLike) -> dict:
    """Read a YAML file into a dict, with a clear error for a missing or malformed file (a
    new copy at every call; the file is parsed again when it changed)."""
    p = Path(path)
    try:
        st = os.stat(p)
        key = (str(p.resolve()), st.st_mtime_ns, st.st_size)
        if key in _YAML_CACHE:
            return copy.deepcopy(_YAML_CACHE[key])
        with open(p, encoding='utf-8') as fh:
            data = yaml.safe_load(fh)
    except FileNotFoundError:
        raise ConfigError(f'{p}: no such file') from None
    except yaml.YAMLError as exc:
        raise ConfigError(f'{p}: not valid YAML: {exc}') from None
    if not isinstance(data, dict):
        raise ConfigError(f'{p}: expected a mapping at the top level')
    _YAML_CACHE[key] = copy.deepcopy(data)
    return data


def ros_parameters(path: str | os.PathLike, node: str = '/**') -> dict:
    """The ``ros__parameters`` mapping of ``node`` in a ROS 2 parameter file."""
    data = load_yaml(path)
    if node not in data or 'ros__parameters' not in (data[node] or {}):
        raise ConfigError(f'{path}: missing "{node}: ros__parameters:" section')
    return data[node]['ros__parameters']


def flatten(mapping: Mapping[str, Any], prefix: str = '') -> dict[str, Any]:
    """``{'a': {'b': 1}}`` -> ``{'a.b': 1}`` (already dotted keys pass through)."""
    flat: dict[str, Any] = {}
    for key, value in mapping.items():
        name = f'{prefix}{key}'
        if isinstance(value, Mapping):
            flat.update(flatten(value, name + '.'))
        else:
            flat[name] = value
    return flat


def unflatten(flat: Mapping[str, Any]) -> dict:
    """Inverse of :func:`flatten`."""
    nested: dict = {}
    for dotted, value in flat.items():
        node = nested
        *path, last = dotted.split('.')
        for key in path:
            node = node.setdefault(key, {})
        node[last] = value
    return nested


def load_params(cls: type, filename: str, node: str, path: str | os.PathLike | None = None,
                overrides: Mapping[str, Any] | None = None,
                ignore: tuple[str, ...] = (), where: str = '',
                extra: Mapping[str, Any] | None = None) -> Any:
    """Build ``cls`` from the ``node: ros__parameters:`` section of a config file.

    Parameters
    ----------
    cls : type
        The frozen parameter dataclass.
    filename : str
        File in :func:`config_dir` used when ``path`` is None.
    node : str
        Node key of the ROS 2 parameter file (``'/**'`` for every node).
    overrides : Mapping, optional
        Values replacing the file's, nested and/or dotted (``{'common.beta': 200.0}``); every
        key must exist in the file.
    ignore : tuple of str
        Top-level sections left out (read by someone else, e.g. the ROS node's ``node``).
    extra : Mapping, optional
        Top-level sections that come from another file (already read), added to the file's
        before the overrides; the file must not have them.

    Raises
    ------
    ConfigError
        Naming the file and the dotted key: missing, unknown, wrong type or out of range.
    """
    import copy

    p = Path(path) if path is not None else config_dir() / filename
    raw = ros_parameters(p, node=node)
    data = {k: copy.deepcopy(v) for k, v in raw.items() if k not in ignore}
    for key, value in (extra or {}).items():
        if key in data:
            raise ConfigError(f'{p}: section {key} is not read from this file (it is '
                              f'described once, elsewhere)')
        data[key] = copy.deepcopy(value)
    try:
        for key, value in flatten(overrides or {}).items():
            set_dotted(data, key, value)
        return build(cls, data, where=where)
    except ConfigError as exc:
        raise ConfigError(f'{p}: {exc}') from None


# ---------------------------------------------------------------- the project's keys

#: Parameters rclpy (or ROS itself) declares on every node, and their prefixes.
ROS_KEYS = ('use_sim_time', 'start_type_description_service', 'qos_overrides.')


@functools.lru_cache(maxsize=4)
def _project_keys(folder: str) -> frozenset[str]:
    keys: set[str] = set()
    for path in sorted(Path(folder).glob('*.yaml')):
        try:
            data = load_yaml(path)
        except ConfigError:
            continue
        for section in data.values():
            if isinstance(section, dict) and isinstance(section.get('ros__parameters'), dict):
                keys.update(flatten(section['ros__parameters']))
    return frozenset(keys)


def project_keys() -> frozenset[str]:
    """Every dotted parameter key a node of the project declares: the keys of every ROS
    parameter file of :func:`~clis_base.params.config_dir` (``sim.yaml``, ``graph.yaml``,
    ``clis.yaml``, ``bridge.yaml``...)."""
    return _project_keys(str(config_dir()))


def is_ros_key(name: str) -> bool:
    """Whether ``name`` is one of :data:`ROS_KEYS` (rclpy's own parameters)."""
    return any(name == k or (k.endswith('.') and name.startswith(k)) for k in ROS_KEYS)


def unknown_key(key: str, known, where: str = '') -> ConfigError:
    """The error for an unknown ``key``: ``WHERE: unknown key KEY; did you mean NEAREST?``
    (the nearest of ``known`` by :func:`difflib.get_close_matches`, if any is close)."""
    near = difflib.get_close_matches(key, sorted(known), n=1, cutoff=0.6)
    hint = f'; did you mean {near[0]}?' if near else ''
    return ConfigError(f'{where + ": " if where else ""}unknown key {key}{hint}')
