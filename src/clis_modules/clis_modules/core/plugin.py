"""The module plug-in API: what a CLIS module provides, and how the framework finds it.

A CLIS module (paper II, docs/design.md §1) is its own state representation and decision
period; everything else is common. The framework keeps, for every module:

- the linear value ``V_i(x) = w_i^T b_i(x)`` (1)(2) and its TD(lambda) learning (8);
- the Gaussian policy ``u ~ N(v_max W_i b, sigma_i^2 I)`` (10) and its learning (9), unless
  the module's policy is fixed;
- the selection by value (3), the semi-MDP discount ``gamma_i`` (11) and the speed limit
  ``v_max,i`` of its period, and the importance-sampling learner (4)-(11);

all on one :class:`~clis_modules.core.modules.ModuleCore`. A *plug-in* provides the rest
(docs/modules.md):

==================  =============================================================================
``name``            the entry-point name (``plugin:`` of a module's config section)
``Params``          its frozen parameter dataclass (``cr_sim.core.params``: ``dataclass``,
                    ``param``), with ``period`` [s], and ``value`` (:class:`ValueParams`) and
                    ``policy`` (:class:`PolicyParams`) sections where learned
``defaults``        the section used when the config file has none (None: it must have one)
``sensors``         the robot topics it reads, of :data:`SENSORS`
``topics``          what its node publishes besides ``~/proposal`` (``{'belief': type}``)
``learned``         whether (9) learns its policy
``model(...)``      its :class:`FeatureModel`: ``features(percept) -> b`` of ``n`` features,
                    the initial ``W`` (2, n) (zeros if None), its sigma, and optional hooks
==================  =============================================================================

The hooks of a module with a state of its own (the place module's Markov localization, paper
III-D): ``reset()`` at an episode start, ``motion(dx, dy, dtheta)`` with the odometry since
the previous decision (the decider integrates the wheel readings for a module that reads
``wheels`` and has this hook) then ``sense(percept)`` before the features of a decision,
``peek(odometry, percept) -> b`` for the features the next ``motion``/``sense`` would give
without changing the state (the learner's ``behaviour_state: resampled``; ``odometry`` None
before the first decision of an episode), ``at_pose(x, y, heading)`` to put the state where it
is once the robot knows it stands at that pose (the place-selection map of Fig. 4; ``reset``
undoes it) and ``display() -> (grid, cell, origin)`` for the belief a module node publishes
(nav_msgs/OccupancyGrid). Hooks with a state are bound methods of the objects holding it (not
closures): a copy of a module (``copy.deepcopy``, a module node's warm-up) then copies the state
once, shared by the copy's hooks.

Plug-ins are found under the entry-point group :data:`ENTRY_POINT_GROUP` (``clis.modules``),
as Gymnasium's third-party environments are: a package declares, in its ``pyproject.toml``::

    [project.entry-points."clis.modules"]
    wall2 = "my_package.wall2:Wall2"

and once it is installed, ``clis experiment --conditions async:innate+wall2`` runs it. The
paper's three modules and ``wall`` are plug-ins of ``clis_modules`` registered the same way.

Conditions (paper IV): ``TIMING:MODULE+MODULE...``, with ``TIMING`` ``async`` (each module on
its own period) or ``sync`` (all on the slowest), parsed by :func:`parse_condition` only;
``innate``, ``view``, ``place``, ``sync`` and ``async`` are names of the paper's five.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike

__all__ = ['ENTRY_POINT_GROUP', 'SENSORS', 'TIMINGS', 'PAPER_CONDITIONS', 'Percept',
           'ModuleContext', 'FeatureModel', 'ModulePlugin', 'plugins', 'get_plugin',
           'Condition', 'parse_condition', 'condition_order', 'solo_condition']

#: Entry-point group of the module plug-ins.
ENTRY_POINT_GROUP = 'clis.modules'
#: What a module may read of the robot (the robot interface's topics, docs/robot.md).
SENSORS = ('camera', 'ir', 'wheels')
#: How the modules of a condition are timed (paper IV).
TIMINGS = ('async', 'sync')
#: The paper's five conditions by name, in the order of its tables (Sec. IV).
PAPER_CONDITIONS = {'innate': 'async:innate', 'view': 'async:view', 'place': 'async:place',
                    'sync': 'sync:innate+view+place', 'async': 'async:innate+view+place'}


class Percept(NamedTuple):
    """What a module reads of the robot at one instant (immutable; a named tuple, not a frozen
    dataclass: one is made at every decision instant, and a frozen dataclass's ``__init__``
    costs several times more).

    Attributes
    ----------
    t : float
        Time of the sensor readings [s].
    dest_bearing : float
        Bearing of the destination relative to the heading [rad]; NaN = not seen (camera).
    d_o : float
        Distance to the nearest obstacle, the smallest IR reading [m].
    landmark_bearings : np.ndarray, shape (M,)
        Bearings of the landmarks [rad] in the arena's order; NaN = not seen (camera).
    ir : np.ndarray, shape (n_ir,), optional
        Every IR ray [m] (``d_o`` is their minimum), in the robot's ray order.
    wheels : np.ndarray, shape (2,), optional
        The wheel readings ``(v_left, v_right)`` [m/s] of the latest step.
    """

    t: float
    dest_bearing: float
    d_o: float
    landmark_bearings: np.ndarray
    ir: np.ndarray | None = None
    wheels: np.ndarray | None = None

    @classmethod
    def from_observation(cls, t: float, obs) -> Percept:
        """From a :class:`cr_sim.core.observation.Observation` (any object with its fields)."""
        return cls(t, obs.dest_bearing, obs.d_o, obs.landmark_bearings,
                   getattr(obs, 'ir', None), getattr(obs, 'wheels', None))


@dataclass(frozen=True)
class ModuleContext:
    """What a plug-in's :meth:`ModulePlugin.model` may use besides its own parameters.

    Attributes
    ----------
    name : str
        The instance name (config section, node name).
    period : float
        The decision period ``tau_i`` of the condition [s] (Sync: the slowest).
    v_max : float
        The speed limit at that period [m/s] (docs/design.md §3).
    common : CommonParams
    landmarks_xy : np.ndarray, shape (M, 2)
        Landmark positions [m], in the order of ``Percept.landmark_bearings``.
    half_size : float or tuple of float
        Half the side of the floor [m], or the half sides ``(x, y)`` of a rectangular one
        (``Arena.floor()``).
    boxes : np.ndarray, shape (K, 4), optional
        Obstacles ``(xmin, ymin, xmax, ymax)`` [m].
    """

    name: str
    period: float
    v_max: float
    common: Any
    landmarks_xy: np.ndarray
    half_size: float | tuple[float, float]
    boxes: np.ndarray | None = None


@dataclass
class FeatureModel:
    """A module's state representation, as its plug-in builds it (module docstring).

    Attributes
    ----------
    n : int
        Number of features.
    features : callable
        ``features(percept) -> b``, a fresh float64 array of shape (n,).
    W : array_like, shape (2, n), optional
        Initial policy weights (mean ``v_max W b``); None = zeros. A fixed policy keeps them.
    sigma : float, optional
        Policy std [m/s]; None = ``policy.sigma`` of a learned module's parameters.
    sigma_blind : float, optional
        Std where the last feature is 1 (the *not visible* feature of the innate module).
    reset, motion, sense, peek, at_pose, display : callable, optional
        The hooks of a module with a state of its own (module docstring).
    state : object, optional
        That state, for inspection (the place module's ``MarkovLocalizer``).
    """

    n: int
    features: Callable[[Percept], np.ndarray]
    W: ArrayLike | None = None
    sigma: float | None = None
    sigma_blind: float | None = None
    reset: Callable[[], None] | None = None
    motion: Callable[[float, float, float], None] | None = None
    sense: Callable[[Percept], None] | None = None
    peek: Callable[[tuple | None, Percept], np.ndarray] | None = None
    at_pose: Callable[[float, float, float], None] | None = None
    display: Callable[[], tuple] | None = None
    state: Any = field(default=None)


class ModulePlugin:
    """Base of a module plug-in (module docstring); subclass it and set the attributes.

    Attributes
    ----------
    name : str
        The entry-point name.
    Params : type
        Frozen parameter dataclass with ``period`` (and ``value``, ``policy`` if learned).
    defaults : Mapping or None
        Its section when the config file has none.
    sensors : tuple of str
        Of :data:`SENSORS`.
    learned : bool
        Whether its policy is learned by (9).
    topics : Mapping
        ``{relative topic: message type}`` its node publishes under its name besides
        ``proposal`` (the place module's ``belief``, from its ``display`` hook), for the
        recorder.
    """

    name: str = ''
    Params: type = type(None)
    defaults: Mapping[str, Any] | None = None
    sensors: tuple[str, ...] = ('camera', 'ir')
    learned: bool = True
    topics: Mapping[str, str] = {}

    def model(self, prm: Any, ctx: ModuleContext) -> FeatureModel:
        """The module's :class:`FeatureModel` for parameters ``prm`` in context ``ctx``."""
        raise NotImplementedError

    def __repr__(self) -> str:
        return f'<module plug-in {self.name!r} ({type(self).__module__})>'


_BUILTIN = {'innate': 'clis_modules.plugins.innate:Innate',
            'view': 'clis_modules.plugins.view:View',
            'place': 'clis_modules.plugins.place:Place',
            'wall': 'clis_modules.plugins.wall:Wall'}
_CACHE: dict[str, ModulePlugin] = {}
_FOUND: dict[str, str] = {}


def _load(target: str) -> Any:
    import importlib
    mod, _, attr = target.partition(':')
    obj = importlib.import_module(mod)
    for part in attr.split('.'):
        obj = getattr(obj, part)
    return obj


def plugins() -> dict[str, str]:
    """Every registered plug-in: ``{name: 'module:attr'}`` of the entry-point group (the
    project's own also when it runs from a source tree without its metadata); the installed
    packages are scanned once per process."""
    if not _FOUND:
        _FOUND.update(_BUILTIN)
        for ep in entry_points(group=ENTRY_POINT_GROUP):
            _FOUND[ep.name] = ep.value
    return dict(_FOUND)


def get_plugin(name: str) -> ModulePlugin:
    """The plug-in registered as ``name`` (loaded once).

    Raises
    ------
    ValueError
        No such plug-in (naming those there are).
    """
    if name in _CACHE:
        return _CACHE[name]
    known = plugins()
    if name not in known:
        raise ValueError(f'no module plug-in {name!r} in entry-point group {ENTRY_POINT_GROUP} '
                         f'(installed: {", ".join(sorted(known))})')
    obj = _load(known[name])
    plugin = obj() if isinstance(obj, type) else obj
    if not isinstance(plugin, ModulePlugin):
        raise ValueError(f'module plug-in {name!r} ({known[name]}) is not a ModulePlugin')
    plugin.name = name
    unknown = set(plugin.sensors) - set(SENSORS)
    if unknown:
        raise ValueError(f'module plug-in {name!r} reads unknown sensors {sorted(unknown)} '
                         f'(one of {", ".join(SENSORS)})')
    _CACHE[name] = plugin
    return plugin


class Condition(NamedTuple):
    """A condition: which modules, timed how (paper IV)."""

    timing: str
    modules: tuple[str, ...]

    def __str__(self) -> str:
        return f'{self.timing}:{"+".join(self.modules)}'


def parse_condition(text: str) -> Condition:
    """``TIMING:MODULE+MODULE...`` (or a name of :data:`PAPER_CONDITIONS`) as a
    :class:`Condition`; the one parser of conditions (the module names are checked against
    the configuration where the modules are made,
    :func:`~clis_modules.core.modules.condition_periods`).

    Raises
    ------
    ValueError
        Not of that form, an unknown timing, no module or one twice.
    """
    if not isinstance(text, str):
        raise ValueError(f'a condition is a string, got {text!r}')
    full = PAPER_CONDITIONS.get(text, text)
    timing, colon, rest = full.partition(':')
    names = tuple(rest.split('+')) if rest else ()
    if not colon or timing not in TIMINGS or not names or not all(
            n.isidentifier() for n in names):
        raise ValueError(f'unknown condition {text!r}: TIMING:MODULE+MODULE... with TIMING '
                         f'{" or ".join(TIMINGS)} (e.g. async:innate+view+place+wall), or one '
                         f'of {", ".join(PAPER_CONDITIONS)}')
    if len(set(names)) != len(names):
        raise ValueError(f'condition {text!r} names a module twice')
    return Condition(timing, names)


def condition_order(text: str) -> tuple:
    """Sort key of conditions: the paper's five in their order, then the others by name."""
    names = list(PAPER_CONDITIONS)
    return (names.index(text), '') if text in names else (len(names), text)


def solo_condition(name: str) -> str:
    """The condition of module instance ``name`` acting alone on its own period."""
    return name if name in PAPER_CONDITIONS else f'async:{name}'
