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
``Params``          its frozen parameter dataclass (``clis_base.params``: ``dataclass``,
                    ``param``), with ``period`` [s], and ``value`` (:class:`ValueParams`) and
                    ``policy`` (:class:`PolicyParams`) sections where learned
``defaults``        the values of its section the config file may leave out (None: none)
``sensors``         the robot topics it reads, of :data:`SENSORS`
``topics``          what its node publishes besides ``~/proposal`` (``{'belief': type}``)
``learned``         whether (9) learns its policy
``model(...)``      its :class:`FeatureModel`, an object: ``n`` features ``features(percept)``,
                    the initial ``W`` (2, n) (zeros if None), its sigma, and the hooks
==================  =============================================================================

A :class:`FeatureModel` is a subclass that overrides :meth:`~FeatureModel.features` and, for a
module with a state of its own (the place module's Markov localization, paper III-D), the
hooks it needs; each hook of the base class does nothing (:meth:`~FeatureModel.peek`: the
features), and the framework calls only those a model overrides (:meth:`FeatureModel.has`):
``reset()`` at an episode start, ``motion(dx, dy, dtheta)`` with the odometry since the
previous decision (the decider integrates the wheel readings for a model with this hook, and a
module node subscribes to ``wheels`` for it) then ``sense(percept)`` before the features of a
decision, ``peek(odometry, percept) -> b`` for the features the next ``motion``/``sense`` would
give without changing the state (the learner's ``behaviour_state: resampled``; ``odometry``
None before the first decision of an episode), ``at_pose(x, y, heading)`` to put the state
where it is once the robot knows it stands at that pose (the place-selection map of Fig. 4;
``reset`` undoes it) and ``display() -> (grid, cell, origin)`` for the belief a module node
publishes (nav_msgs/OccupancyGrid). The state is the model's (its attributes): a copy of a
module (``copy.deepcopy``, a module node's warm-up) copies it with the model.

Plug-ins are found under the entry-point group :data:`ENTRY_POINT_GROUP` (``clis.modules``),
as Gymnasium's third-party environments are: a package declares, in its ``pyproject.toml``::

    [project.entry-points."clis.modules"]
    wall2 = "my_package.wall2:Wall2"

and once it is installed, ``clis experiment --conditions async:innate+wall2`` runs it. The
paper's three modules and ``wall`` are entry points of ``clis_modules`` like any other: its
``setup.py`` reads them from :data:`OWN_ENTRY_POINTS`, the file ``plugins/entry_points.txt``
of the package (the format of a distribution's ``entry_points.txt``). Code run from a source
tree without the package's metadata (``PYTHONPATH=src/...``, e.g. a commit's code from ``git
archive``) reads that file instead, so there is one list either way (:func:`plugins`).

Conditions (paper IV): ``TIMING:MODULE+MODULE...``, with ``TIMING`` ``async`` (each module on
its own period) or ``sync`` (all on the slowest), parsed by :func:`parse_condition` only;
``innate``, ``view``, ``place``, ``sync`` and ``async`` are names of the paper's five.
"""

from __future__ import annotations

from collections.abc import Mapping
import configparser
from dataclasses import dataclass
from importlib.metadata import PackageNotFoundError, distribution, entry_points
import importlib.resources
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike

__all__ = ['ENTRY_POINT_GROUP', 'OWN_ENTRY_POINTS', 'SENSORS', 'TIMINGS', 'PAPER_CONDITIONS',
           'HOOKS', 'Percept', 'Floor', 'ModuleContext', 'FeatureModel', 'ModulePlugin',
           'plugins', 'get_plugin', 'read_entry_points', 'Condition', 'parse_condition',
           'condition_order', 'solo_condition']

#: Entry-point group of the module plug-ins.
ENTRY_POINT_GROUP = 'clis.modules'
#: The file of ``clis_modules`` that lists its own plug-ins (``[clis.modules]`` ``name =
#: module:attr`` lines): what its ``setup.py`` registers, and what :func:`plugins` reads where
#: the package's metadata is not installed.
OWN_ENTRY_POINTS = ('clis_modules.plugins', 'entry_points.txt')
#: The hooks of a :class:`FeatureModel`.
HOOKS = ('reset', 'motion', 'sense', 'peek', 'at_pose', 'display')
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
class Floor:
    """The arena's floor, a rectangle [m] (``cr_sim.core.arena.Arena.bounds``); the walls are
    its border.

    Attributes
    ----------
    xmin, ymin, xmax, ymax : float
        Its west, south, east and north sides [m].
    """

    xmin: float
    ymin: float
    xmax: float
    ymax: float

    def __post_init__(self) -> None:
        if not (self.xmin < self.xmax and self.ymin < self.ymax):
            raise ValueError(f'a floor needs xmin < xmax and ymin < ymax, got {self}')

    @classmethod
    def square(cls, half: float) -> Floor:
        """The square ``[-half, half]^2`` centred at the origin (the paper's arena)."""
        half = float(half)
        return cls(-half, -half, half, half)

    @classmethod
    def of(cls, arena: Any) -> Floor:
        """The floor of a ``cr_sim.core.arena.Arena`` (its ``bounds``)."""
        return cls(*(float(v) for v in arena.bounds))

    @property
    def half(self) -> float | None:
        """Half the side of a square centred at the origin; None for any other rectangle."""
        return self.xmax if self.xmin == self.ymin == -self.xmax == -self.ymax else None


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
    floor : Floor
        The floor.
    boxes : np.ndarray, shape (K, 4), optional
        Obstacles ``(xmin, ymin, xmax, ymax)`` [m].
    """

    name: str
    period: float
    v_max: float
    common: Any
    landmarks_xy: np.ndarray
    floor: Floor
    boxes: np.ndarray | None = None


class FeatureModel:
    """A module's state representation, as its plug-in builds it (module docstring): subclass
    it, override :meth:`features` and the hooks the module needs.

    Parameters
    ----------
    n : int
        Number of features.
    W : array_like, shape (2, n), optional
        Initial policy weights (mean ``v_max W b``); None = zeros. A fixed policy keeps them.
    sigma : float, optional
        Policy std [m/s]; None = ``policy.sigma`` of a learned module's parameters.
    sigma_blind : float, optional
        Std where the last feature is 1 (the *not visible* feature of the innate module).

    Attributes
    ----------
    state : object
        The module's own state, for inspection (the place module's ``MarkovLocalizer``);
        None by default.
    """

    state: Any = None

    def __init__(self, n: int, W: ArrayLike | None = None, sigma: float | None = None,  # noqa: N803
                 sigma_blind: float | None = None) -> None:
        self.n = int(n)
        self.W = W
        self.sigma = sigma
        self.sigma_blind = sigma_blind

    def features(self, percept: Percept) -> np.ndarray:
        """``b``, a fresh float64 array of shape (n,), of what the module reads now (and of
        its state)."""
        raise NotImplementedError(f'{type(self).__name__}.features')

    def reset(self) -> None:
        """Episode start (default: nothing)."""

    def motion(self, dx: float, dy: float, dtheta: float) -> None:
        """The odometry since the previous decision, in the robot frame at that decision
        ([m], [m], [rad]); called before :meth:`sense` at each decision but the first of an
        episode (default: nothing, and no odometry is integrated for the module)."""

    def sense(self, percept: Percept) -> None:
        """The readings at a decision, before its :meth:`features` (default: nothing)."""

    def peek(self, odometry: tuple[float, float, float] | None,
             percept: Percept) -> np.ndarray:
        """The features the next :meth:`motion` (``odometry``; None before the first decision
        of an episode) and :meth:`sense` would give, the state left as it is (default:
        :meth:`features`)."""
        return self.features(percept)

    def at_pose(self, x: float, y: float, heading: float) -> None:
        """Put the state where it is once the robot knows it stands at ``(x, y, heading)``
        ([m], [m], [rad]; default: nothing)."""

    def display(self) -> tuple[np.ndarray, float, tuple[float, float]] | None:
        """The belief a module node publishes (nav_msgs/OccupancyGrid): ``(grid, cell,
        origin)``, the grid (nx, ny) in [0, 1], its cell side [m] and its south-west corner
        [m]; None (the default): nothing to publish."""
        return None

    @classmethod
    def has(cls, hook: str) -> bool:
        """Whether this model overrides ``hook`` (one of :data:`HOOKS`): the framework calls
        only the hooks a model overrides."""
        if hook not in HOOKS:
            raise ValueError(f'no hook {hook!r} (one of {", ".join(HOOKS)})')
        return getattr(cls, hook) is not getattr(FeatureModel, hook)


class ModulePlugin:
    """Base of a module plug-in (module docstring); subclass it and set the attributes.

    Attributes
    ----------
    name : str
        The entry-point name.
    Params : type
        Frozen parameter dataclass with ``period`` (and ``value``, ``policy`` if learned).
    defaults : Mapping or None
        Values of its section that a config file may leave out (all of them: the module runs
        without a section); None = every key must be given.
    sensors : tuple of str
        Of :data:`SENSORS`.
    learned : bool
        Whether its policy is learned by (9).
    topics : Mapping
        ``{relative topic: message type}`` its node publishes under its name besides
        ``proposal`` (the place module's ``belief``, from its ``display`` hook), for the
        recorder and the live view.
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


_CACHE: dict[str, ModulePlugin] = {}
_FOUND: dict[str, str] = {}


def _load(target: str) -> Any:
    import importlib
    mod, _, attr = target.partition(':')
    obj = importlib.import_module(mod)
    for part in attr.split('.'):
        obj = getattr(obj, part)
    return obj


def read_entry_points(text: str) -> dict[str, dict[str, str]]:
    """``{group: {name: 'module:attr'}}`` of an ``entry_points.txt`` text (INI sections, one
    ``name = module:attr`` per line; ``setup.py`` of ``clis_modules`` reads
    :data:`OWN_ENTRY_POINTS` with it)."""
    ini = configparser.ConfigParser(delimiters=('=',), interpolation=None)
    ini.optionxform = str                          # type: ignore[assignment] # names as written
    ini.read_string(text)
    return {group: dict(ini[group]) for group in ini.sections()}


def _own_entry_points() -> dict[str, str]:
    package, filename = OWN_ENTRY_POINTS
    text = importlib.resources.files(package).joinpath(filename).read_text(encoding='utf-8')
    return read_entry_points(text).get(ENTRY_POINT_GROUP, {})


def plugins() -> dict[str, str]:
    """Every registered plug-in: ``{name: 'module:attr'}`` of the entry-point group, read once
    per process. Where ``clis_modules`` runs without its metadata (from a source tree on
    ``PYTHONPATH`` alone) its own are read from :data:`OWN_ENTRY_POINTS`, the file its
    ``setup.py`` registers."""
    if not _FOUND:
        for ep in entry_points(group=ENTRY_POINT_GROUP):
            _FOUND[ep.name] = ep.value
        try:
            distribution('clis_modules')
        except PackageNotFoundError:
            for name, value in _own_entry_points().items():
                _FOUND.setdefault(name, value)
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
