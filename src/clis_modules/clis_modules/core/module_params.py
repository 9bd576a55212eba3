"""The modules' parameters and the conditions of a configuration: what ``config/clis.yaml``
says of the modules (paper II, IV; docs/design.md §1-3), read and checked once.

The sections every module shares (``common``: the discount (11) and the speed limit's
``d_react``; ``value``, ``policy``), the module instances (Nav2-style: ``modules`` lists the
names, each instance a section with ``plugin:`` and that plug-in's parameters), and what a
condition makes of them: each module's period ``tau_i``, discount ``gamma_i`` (11), speed limit
``v_max,i = min(v_wheel_max, d_react / tau_i)`` and sensors. :mod:`clis_modules.core.modules`
builds the modules themselves from it.
"""

from __future__ import annotations

from collections.abc import Mapping
import copy
import dataclasses
import difflib
import typing
from typing import Any, Protocol

from clis_base.params import ConfigError, build, build_fields, dataclass, load_params, param

from clis_modules.core.arbiter import ArbiterParams
from clis_modules.core.plugin import (
    PAPER_CONDITIONS,
    ModulePlugin,
    get_plugin,
    parse_condition,
    plugins,
)
from clis_modules.core.value import gamma_i

__all__ = [
    'CONDITIONS', 'CommonParams', 'ValueParams', 'PolicyParams', 'ModuleSetParams',
    'load_module_params', 'instance_defaults', 'merge_section', 'ModuleParamsLike',
    'speed_limit', 'module_gamma', 'condition_periods', 'condition_sensors',
]

#: The paper's experimental conditions by name (Sec. IV); any ``TIMING:MODULE+...`` is one too
#: (:func:`clis_modules.core.plugin.parse_condition`).
CONDITIONS = tuple(PAPER_CONDITIONS)


# ------------------------------------------------------------------------------ parameters

@dataclass(frozen=True)
class CommonParams:
    """Shared by every module (``clis.yaml`` section ``common``)."""

    gamma: float = param(0.0, 1.0, doc='common discount rate gamma per base tick, (11)')
    base_tick: float = param(1e-3, 10.0, doc='base tick Delta of (11) [s]')
    beta: float = param(0.0, 1e6, doc='inverse temperature beta of the selection (3)')
    epsilon: float = param(0.0, 1e6, doc='constant epsilon of the truncated ratio (7)')
    d_react: float = param(1e-3, 10.0, doc='distance allowed between decisions [m]')
    v_wheel_max: float = param(0.01, 1.3, doc='hard limit of each wheel [m/s]')


@dataclass(frozen=True)
class ValueParams:
    """Linear value (1)(2) and its TD(lambda) learning (8) (section ``<module>.value``)."""

    alpha: float = param(0.0, 10.0, doc='step size alpha_i of TD(lambda) (8)')
    v_init: float = param(-100.0, 100.0, doc='initial weight of every value feature')


@dataclass(frozen=True)
class PolicyParams:
    """Learned Gaussian policy (10) and its gradient learning (9) (``<module>.policy``)."""

    alpha: float = param(0.0, 10.0, doc='step size alpha_i of the policy gradient (9)')
    sigma: float = param(1e-3, 5.0, doc='initial std sigma_i of each wheel [m/s]')
    learn_sigma: bool = param(doc='also learn sigma_i by (9)')
    sigma_min: float = param(1e-3, 5.0, doc='lower bound of a learned sigma_i [m/s]')
    sigma_max: float = param(1e-3, 5.0, doc='upper bound of a learned sigma_i [m/s]')
    alpha_sigma: float = param(0.0, 10.0, doc='step size of sigma_i in (9)')

    def validate(self) -> None:
        """``sigma_min <= sigma <= sigma_max``."""
        if not self.sigma_min <= self.sigma <= self.sigma_max:
            raise ValueError(f'need sigma_min <= sigma <= sigma_max, got {self.sigma_min}, '
                             f'{self.sigma}, {self.sigma_max}')


@dataclass(frozen=True)
class ModuleSetParams:
    """The sections of ``config/clis.yaml`` that the modules and the arbiter read (the learner
    reads them too, plus its own: ``clis_learner.core.config.ClisParams``).

    Besides its fields, every section named in ``modules`` or after a registered plug-in is a
    module instance: ``plugin`` (default: the section's name) and that plug-in's parameters,
    validated at load. A section may give only some of them: it is merged, key by key, over
    its plug-in's defaults (:func:`instance_defaults`). :meth:`module` gives an instance's
    plug-in and parameters (those of the plug-in's ``defaults`` when the file has no section
    for it); ``params.NAME`` its parameters.
    """

    common: CommonParams = param(doc='section common')
    modules: tuple[str, ...] = param(doc='the module instances configured in this file (each '
                                     'a section with its plugin and parameters)')
    arbiter: ArbiterParams = param(doc='section arbiter')
    #: ``(name, plugin, parameters)`` of every configured instance (not a key of the file)
    instances: tuple = dataclasses.field(default=(), kw_only=True,
                                         metadata={'doc': 'module instances'})

    @classmethod
    def __build_params__(cls, mapping: Any, where: str = '') -> ModuleSetParams:
        """:func:`clis_base.params.build` of the fields, then of each instance section."""
        if not hasattr(mapping, 'items'):
            raise ConfigError(f'{where or cls.__name__} must be a mapping')
        own = {f.name for f in dataclasses.fields(cls)} - {'instances'}
        listed = mapping.get('modules', ())
        listed = tuple(listed) if isinstance(listed, (list, tuple)) else ()
        prefix = f'{where}.' if where else ''
        registered = plugins()
        instances = []
        for name, section in mapping.items():
            if name in own:
                continue
            if name not in listed and name not in registered:
                raise ConfigError(f'unknown key {prefix}{name}; allowed keys: '
                                  + ', '.join(sorted(own | set(listed))))
            instances.append((name, *_instance(name, section, prefix + name, mapping)))
        obj = build_fields(cls, {k: v for k, v in mapping.items() if k in own}, where)
        return dataclasses.replace(obj, instances=tuple(instances))

    def module(self, name: str) -> tuple[ModulePlugin, Any]:
        """The plug-in and parameters of module instance ``name``.

        Raises
        ------
        ValueError
            Neither an instance of this file nor a plug-in with ``defaults``.
        """
        for inst, plugin, prm in self.instances:
            if inst == name:
                return get_plugin(plugin), prm
        if name not in plugins():
            raise ValueError(f'unknown module {name!r}: not a section of the CLIS parameters '
                             f'(instances: {", ".join(i[0] for i in self.instances)}) nor a '
                             f'plug-in (installed: {", ".join(sorted(plugins()))})')
        plugin = get_plugin(name)
        if plugin.defaults is None:
            raise ConfigError(f'module {name!r}: no section {name} in the CLIS parameters and '
                              'its plug-in has no defaults')
        return plugin, build(plugin.Params, dict(plugin.defaults), where=name)

    def __getattr__(self, name: str) -> Any:
        if name.startswith('_'):
            raise AttributeError(name)
        for inst, _, prm in object.__getattribute__(self, 'instances'):
            if inst == name:
                return prm
        raise AttributeError(f'{type(self).__name__} has no field or module instance {name!r}')


def _instance(name: str, section: Any, where: str, mapping: Mapping[str, Any]
              ) -> tuple[str, Any]:
    """``(plugin name, parameters)`` of the instance section ``section`` of ``mapping``."""
    if not hasattr(section, 'items'):
        raise ConfigError(f'{where} must be a mapping (a module instance: plugin and parameters)')
    section = dict(section)
    plugin_name = section.pop('plugin', name)
    try:
        plugin = get_plugin(plugin_name)
    except ValueError as exc:
        raise ConfigError(f'{where}.plugin: {exc}') from None
    merged = merge_section(plugin.Params, instance_defaults(plugin, name, mapping), section,
                           where)
    return plugin_name, build(plugin.Params, merged, where=where)


def instance_defaults(plugin: ModulePlugin, name: str, mapping: Mapping[str, Any]) -> dict:
    """What the section of instance ``name`` of ``plugin`` is merged over: the plug-in's
    ``defaults``, and over them, for an instance not named after its plug-in, the section of
    ``mapping`` that is (an instance of that plug-in): in ``config/clis.yaml``,
    ``view_fast: {plugin: view, period: 0.25}`` is the ``view`` section with another period."""
    base = copy.deepcopy(dict(plugin.defaults or {}))
    same = mapping.get(plugin.name) if name != plugin.name else None
    if hasattr(same, 'items') and same.get('plugin', plugin.name) == plugin.name:
        own = {k: copy.deepcopy(v) for k, v in same.items() if k != 'plugin'}
        base = merge_section(plugin.Params, base, own, plugin.name)
    return base


def merge_section(cls: type, base: Mapping[str, Any], section: Mapping[str, Any],
                  where: str) -> dict:
    """``section`` over ``base``, key by key (nested sections of ``cls``'s dataclass fields
    merged likewise); the values are checked by :func:`clis_base.params.build` after.

    Raises
    ------
    ConfigError
        A key of ``section`` that is not a field of ``cls``, naming the nearest one.
    """
    fields = [f.name for f in dataclasses.fields(cls)]
    hints = typing.get_type_hints(cls)
    out = dict(base)
    for key, value in section.items():
        if key not in fields:
            near = difflib.get_close_matches(str(key), fields, n=1, cutoff=0.6)
            hint = f'; did you mean {where}.{near[0]}?' if near else ''
            raise ConfigError(f'unknown key {where}.{key}{hint} (allowed keys: '
                              f'{", ".join(sorted(fields))})')
        sub = hints[key]
        if dataclasses.is_dataclass(sub) and isinstance(value, Mapping) \
                and isinstance(out.get(key), Mapping):
            out[key] = merge_section(sub, out[key], value, f'{where}.{key}')
        else:
            out[key] = value
    return out


def load_module_params(path: str | None = None, overrides: dict | None = None
                       ) -> ModuleSetParams:
    """:class:`ModuleSetParams` from ``/**: ros__parameters:`` of ``clis.yaml`` (or ``path``),
    validated (a bad value raises ``ConfigError`` naming the file and the dotted key)."""
    return load_params(ModuleSetParams, 'clis.yaml', '/**', path, overrides,
                       ignore=('learner',))


class ModuleParamsLike(Protocol):
    """What :func:`make_modules` reads (``clis_learner.core.config.ClisParams`` has it)."""

    common: CommonParams

    def module(self, name: str) -> tuple[ModulePlugin, Any]: ...


# ------------------------------------------------------------------------------ helpers

def speed_limit(common: CommonParams, period: float) -> float:
    """``v_max,i = min(v_wheel_max, d_react / tau_i)`` [m/s] (docs/design.md §3)."""
    return min(common.v_wheel_max, common.d_react / period)


def module_gamma(common: CommonParams, period: float) -> float:
    """Semi-MDP discount of a module with period ``period``, eq. (11) (:func:`gamma_i`)."""
    return gamma_i(common.gamma, period, common.base_tick)


def condition_periods(params: ModuleParamsLike, condition: str) -> list[tuple[str, float]]:
    """``(name, tau_i)`` of the modules of a condition (paper IV, docs/design.md §3), in the
    condition's order: each on its own period (``async:...``; ``innate``, ``view``, ``place``
    and ``async`` are ``async`` conditions) or all on the slowest one (``sync:...``).

    Raises
    ------
    ValueError
        A condition not of the form (:func:`~clis_modules.core.plugin.parse_condition`) or
        naming an unknown module.
    """
    cond = parse_condition(condition)
    own = [(name, float(params.module(name)[1].period)) for name in cond.modules]
    if cond.timing == 'sync':
        slowest = max(tau for _, tau in own)
        return [(name, slowest) for name, _ in own]
    return own


def condition_sensors(params: ModuleParamsLike, condition: str) -> dict[str, tuple[str, ...]]:
    """``{module: the sensors its plug-in reads}`` of the modules of ``condition``."""
    return {name: tuple(params.module(name)[0].sensors)
            for name in parse_condition(condition).modules}
