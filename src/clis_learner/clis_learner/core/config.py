"""All CLIS parameters, read from ``config/clis.yaml`` (``/**: ros__parameters:``).

Sections: ``common`` (gamma, base tick, beta, epsilon, speed limit), ``innate``, ``view``,
``place`` (:mod:`clis_modules.core.modules`), ``arbiter`` (:mod:`clis_modules.core.arbiter`),
``learner`` (here). Every value is range-checked at load; a bad one raises
:class:`~clis_base.params.ConfigError` naming the file and the dotted key.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
import hashlib
import json
import os
from pathlib import Path
from typing import Any

from clis_base.params import (
    ConfigError,
    config_dir,
    dataclass,
    flatten,
    identity_dict,
    is_ros_key,
    load_params,
    load_yaml,
    param,
    project_keys,
    ros_parameters,
    unknown_key,
)
from clis_modules.core.modules import ModuleSetParams

from clis_learner.core.corrections import BEHAVIOUR_STATES, BEHAVIOURS, CORRECTIONS
from clis_learner.core.resample import RESAMPLE_METHODS
from clis_learner.core.updates import POLICY_STEPS, POLICY_UPDATES, STEP_NORMS, VALUE_UPDATES

__all__ = ['LearnerParams', 'ClisParams', 'load_clis_params', 'params_hash', 'CLIS_NODE',
           'DEFAULT_PRESET', 'PRESET_NAMES', 'preset_path', 'preset_overrides',
           'preset_groups', 'PRESET_GROUPS',
           'check_overrides', 'check_params_file']

#: Node key of the parameter file: every node reads the same CLIS parameters.
CLIS_NODE = '/**'


@dataclass(frozen=True)
class LearnerParams:
    """Learning from one episode (``clis.yaml`` section ``learner``)."""

    resample: str = param(choices=RESAMPLE_METHODS,
                          doc='actions onto each module grid: cubic spline or zero-order hold')
    correction: str = param(choices=tuple(CORRECTIONS), doc='importance-sampling correction')
    lambda_: float = param(0.0, 1.0, doc='trace decay lambda_i of TD(lambda) (8)')
    policy_step: str = param(choices=POLICY_STEPS,
                             doc="'paper' = (9) on the gradient of (10) with its mean in m/s; "
                                 "'dimensionless' = on the gradient with respect to W in units "
                                 "of v_max (v_max^2 times less); 'scaled' = times the inverse "
                                 'Fisher information of the Gaussian (10)')
    behaviour_state: str = param(choices=BEHAVIOUR_STATES,
                                 doc="state at which the behaviour's density of (6)(7) is "
                                     "scored: 'resampled' = its features at the target's "
                                     "instant l tau_i (paper (6)); 'held' = at its latest "
                                     'decision <= l tau_i')
    value_update: str = param(choices=VALUE_UPDATES,
                              doc="'paper' = TD(lambda) with the IS product (8); 'retrace' = "
                                  'per-decision truncated traces (Retrace / V-trace)')
    policy_update: str = param(choices=POLICY_UPDATES,
                               doc="'paper' = (9) with the episode's IS product; 'offpac' = "
                                   'off-policy actor-critic, per-step truncated ratio, V_i '
                                   'baseline')
    behaviour: str = param(choices=BEHAVIOURS,
                           doc="density of the behaviour in the ratio: 'acting' module (6)(7) "
                               "or the selection 'mixture' sum_j Pr(j|x) pi_j (balance "
                               'heuristic)')
    rho_bar: float = param(0.0, 1e6, doc='truncation level of the per-step ratio of retrace '
                                         '/ offpac (V-trace rho-bar = c-bar)')
    imitation: float = param(0.0, 1e3, doc='weight kappa of the imitation term kappa max(0, '
                             'G - V_i) d ln pi (CRAIL / self-imitation); 0 = off (paper)')
    max_mean_step: float = param(0.0, 1e3, doc='trust region: largest change of the policy '
                                 'mean at a state of the episode, in sigma; 0 = none (paper)')
    step_norm: str = param(choices=STEP_NORMS,
                           doc="'none' = alpha as given; 'features' = alpha / (b . b) per step "
                               '(normalised LMS: each step moves V and the mean at x by alpha '
                               "of its error, whatever the feature mass); 'bounded' = "
                               "'features' with each TD step bounded so that no value of the "
                               "episode's states moves by more than alpha |delta|")


@dataclass(frozen=True)
class ClisParams(ModuleSetParams):
    """Everything in ``clis.yaml``: the modules' and arbiter's sections, and the learner's."""

    learner: LearnerParams = param(doc='section learner')


#: The changes of a preset that ``clis experiment --ablation`` toggles together (one row each);
#: a key of a preset file in no group is a change of its own.
PRESET_GROUPS: dict[str, tuple[str, ...]] = {
    'retrace': ('learner.value_update', 'learner.rho_bar', 'learner.correction'),
    'offpac': ('learner.policy_update',),
    'imitation': ('learner.imitation',),
    'mixture': ('learner.behaviour',),
    'selection': ('arbiter.rule', 'common.beta', 'arbiter.scale_min'),
    'steps': ('learner.step_norm', 'learner.policy_step', 'learner.max_mean_step',
              'view.policy.alpha', 'place.policy.alpha'),
    'place_rbf': ('place.features.kind',),
}


#: The preset ``clis run``, ``clis experiment`` and ``make run`` use unless told otherwise: the
#: one that learns (docs/results.md). ``paper``, the rules exactly as printed, diverges in most
#: runs (the divergence guard, :mod:`clis_learner.core.guard`, says so).
DEFAULT_PRESET = 'improved'


def PRESET_NAMES() -> tuple[str, ...]:  # noqa: N802 - a constant computed from the files
    """``paper`` (config/clis.yaml) and NAME of every ``config/clis_NAME.yaml``."""
    names = sorted(p.stem[len('clis_'):] for p in config_dir().glob('clis_*.yaml'))
    return ('paper', *names)


def preset_overrides(name: str) -> dict[str, Any]:
    """The dotted overrides of preset ``name`` (``{}`` for ``paper``): the
    ``/**: ros__parameters:`` of ``config/clis_NAME.yaml``, a partial CLIS parameter file
    (ROS nodes take it as a second ``--params-file`` after clis.yaml)."""
    path = preset_path(name)
    return {} if path is None else flatten(ros_parameters(path, CLIS_NODE))


def preset_path(name: str) -> Path | None:
    """The partial parameter file of preset ``name`` (``config/clis_NAME.yaml``; None for
    ``paper``, which is config/clis.yaml alone). ValueError for an unknown preset."""
    if name == 'paper':
        return None
    path = config_dir() / f'clis_{name}.yaml'
    if not path.is_file():
        raise ValueError(f'unknown preset {name!r}: choose from {", ".join(PRESET_NAMES())}')
    return path


def preset_groups(name: str) -> dict[str, dict[str, Any]]:
    """The overrides of preset ``name`` grouped into its changes (:data:`PRESET_GROUPS`),
    in the order of the groups; keys in no group form a group of their own."""
    flat = preset_overrides(name)
    out: dict[str, dict[str, Any]] = {}
    for group, keys in PRESET_GROUPS.items():
        items = {k: flat[k] for k in keys if k in flat}
        if items:
            out[group] = items
    for k, v in flat.items():
        if not any(k in items for items in out.values()):
            out[k] = {k: v}
    return out


def load_clis_params(path: str | os.PathLike | None = None,
                     overrides: Mapping[str, Any] | None = None,
                     source: str = 'override') -> ClisParams:
    """Read ``/**: ros__parameters:`` of a CLIS parameter file into :class:`ClisParams`.

    Parameters
    ----------
    path : path-like, optional
        Default ``config_dir() / 'clis.yaml'``.
    overrides : Mapping, optional
        Values replacing the file's, nested (``{'common': {'beta': 200.0}}``) and/or dotted
        (``{'common.beta': 200.0}``). Every key must exist in the file
        (:func:`check_overrides`).
    source : str
        Where the overrides come from (``--set``, a parameter file...): the error names it.

    Raises
    ------
    ConfigError
        A bad file names the file and the dotted key (missing, unknown, wrong type or out of
        range); a bad override names ``source`` and the key (an unknown one with the nearest
        known key), not the file.
    """
    params = load_params(ClisParams, 'clis.yaml', CLIS_NODE, path)
    if not overrides:
        return params
    file = Path(path) if path is not None else config_dir() / 'clis.yaml'
    check_overrides(overrides, source, flatten(ros_parameters(file, CLIS_NODE)))
    try:
        return load_params(ClisParams, 'clis.yaml', CLIS_NODE, path, overrides)
    except ConfigError as exc:             # the file is fine (above): the override is not
        raise ConfigError(f'{source}: {str(exc).removeprefix(f"{file}: ")}') from None


def check_overrides(overrides: Mapping[str, Any], source: str,
                    known: Collection[str] | None = None) -> dict[str, Any]:
    """The overrides as dotted keys, each of which must be a key of ``known``.

    The one check of parameter keys given by the user, ``clis experiment --set KEY=VALUE``
    and ``clis run --params FILE`` alike (docs/design.md, parameters).

    Parameters
    ----------
    overrides : Mapping
        Nested and/or dotted.
    source : str
        What the user gave them with (``--set``, the file): the error names it.
    known : collection of str, optional
        The allowed dotted keys; default those of ``config/clis.yaml``.

    Raises
    ------
    ConfigError
        ``SOURCE: unknown key KEY; did you mean NEAREST?`` (the nearest known key by
        :func:`difflib.get_close_matches`, when one is close).
    """
    flat = flatten(overrides or {})
    if known is None:
        known = flatten(ros_parameters(config_dir() / 'clis.yaml', CLIS_NODE))
    for key in flat:
        if key not in known:
            raise unknown_key(key, known, source)
    return flat


def check_params_file(path: str | os.PathLike) -> dict[str, Any]:
    """Check a ROS 2 parameter file a user gives every node (``clis run --params FILE``).

    Every key must be one that a node of the project declares (:func:`check_overrides`
    against :func:`clis_base.params.project_keys`), and the CLIS keys
    (``config/clis.yaml``) must hold allowed values (:func:`load_clis_params`); the nodes check
    the others' values at start.

    Returns
    -------
    dict
        The file's dotted keys and values (all node sections together).

    Raises
    ------
    ConfigError
        Naming the file and the key: not a parameter file, unknown key (with the nearest
        known), a CLIS value of the wrong type or out of range.
    """
    data = load_yaml(path)
    flat: dict[str, Any] = {}
    for node, section in data.items():
        if not isinstance(section, Mapping) or set(section) != {'ros__parameters'} \
                or not isinstance(section['ros__parameters'], Mapping):
            raise ConfigError(f'{path}: {node}: expected "{node}: ros__parameters: KEY: '
                              'VALUE" (a ROS 2 parameter file)')
        flat.update(flatten(section['ros__parameters']))
    check_overrides({k: v for k, v in flat.items() if not is_ros_key(k)}, str(path),
                    project_keys())
    clis = flatten(ros_parameters(config_dir() / 'clis.yaml', CLIS_NODE))
    load_clis_params(overrides={k: v for k, v in flat.items() if k in clis}, source=str(path))
    return flat


def params_hash(params: Any) -> str:
    """Short SHA-256 of a parameter dataclass (canonical JSON): identifies a configuration."""
    text = json.dumps(identity_dict(params), sort_keys=True, separators=(',', ':'))
    return hashlib.sha256(text.encode('utf-8')).hexdigest()[:16]
