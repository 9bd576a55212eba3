"""All CLIS parameters, read from ``config/clis.yaml`` (``/**: ros__parameters:``).

Sections: ``common`` (gamma, base tick, beta, epsilon, speed limit), ``innate``, ``view``,
``place`` (:mod:`clis_modules.core.modules`), ``arbiter`` (:mod:`clis_modules.core.arbiter`),
``learner`` (here). Every value is range-checked at load; a bad one raises
:class:`~cr_sim.core.params.ConfigError` naming the file and the dotted key.
"""

from __future__ import annotations

from collections.abc import Mapping
import hashlib
import json
import os
from typing import Any

from clis_modules.core.modules import ModuleSetParams
from cr_sim.core.params import (
    as_dict,
    dataclass,
    load_params,
    param,
)

from clis_learner.core.corrections import CORRECTIONS
from clis_learner.core.resample import RESAMPLE_METHODS

__all__ = ['LearnerParams', 'ClisParams', 'load_clis_params', 'params_hash', 'CLIS_NODE']

#: Node key of the parameter file: every node reads the same CLIS parameters.
CLIS_NODE = '/**'


@dataclass(frozen=True)
class LearnerParams:
    """Learning from one episode (``clis.yaml`` section ``learner``)."""

    resample: str = param(choices=RESAMPLE_METHODS,
                          doc='actions onto each module grid: cubic spline or zero-order hold')
    correction: str = param(choices=tuple(CORRECTIONS), doc='importance-sampling correction')
    lambda_: float = param(0.0, 1.0, doc='trace decay lambda_i of TD(lambda) (8)')
    policy_step: str = param(choices=('raw', 'scaled'),
                             doc='(9) on the raw gradient, or scaled by the inverse Fisher '
                                 'information of the Gaussian (10)')


@dataclass(frozen=True)
class ClisParams(ModuleSetParams):
    """Everything in ``clis.yaml``: the modules' and arbiter's sections, and the learner's."""

    learner: LearnerParams = param(doc='section learner')


def load_clis_params(path: str | os.PathLike | None = None,
                     overrides: Mapping[str, Any] | None = None) -> ClisParams:
    """Read ``/**: ros__parameters:`` of a CLIS parameter file into :class:`ClisParams`.

    Parameters
    ----------
    path : path-like, optional
        Default ``config_dir() / 'clis.yaml'``.
    overrides : Mapping, optional
        Values replacing the file's, nested (``{'common': {'beta': 200.0}}``) and/or dotted
        (``{'common.beta': 200.0}``). Every key must exist in the file.

    Raises
    ------
    ConfigError
        Naming the file and the dotted key: missing, unknown, wrong type or out of range.
    """
    return load_params(ClisParams, 'clis.yaml', CLIS_NODE, path, overrides)


def params_hash(params: Any) -> str:
    """Short SHA-256 of a parameter dataclass (canonical JSON): identifies a configuration."""
    text = json.dumps(as_dict(params), sort_keys=True, separators=(',', ':'))
    return hashlib.sha256(text.encode('utf-8')).hexdigest()[:16]
