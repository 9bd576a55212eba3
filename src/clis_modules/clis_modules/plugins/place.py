"""The place-based module M_pl (paper III-D): where the robot believes it is.

Its state is the belief of a grid Markov localization
(:class:`~clis_modules.core.localization.MarkovLocalizer`) over the arena's free cells and
heading bins, driven by the module's hooks: ``motion`` (the motion update with the odometry
since the previous decision, ``b(x') <- sum_x Pr(x' | x, u) b(x)``) and ``sense`` (the landmark
update, ``b(x) <- eta Pr(s | x) b(x)``), in that order before each decision; ``reset`` (a
uniform belief at an episode start); ``peek`` (the belief those two would give, without
committing it: the learner's ``behaviour_state: resampled``).

Its features are the belief itself (``features.kind = belief``, one per grid cell), or ``P b``
(``rbf``): the belief-weighted mean of normalised Gaussian RBFs over the cells' poses
``(x, y, theta)``, ``P[k, c] = phi_k(pose_c)`` with ``sum_k P[k, c] = 1``, so a localised
belief activates the RBFs around its cell and what is learned at one cell carries to its
neighbours.
"""

from __future__ import annotations

import math

from clis_base.params import dataclass, param
import numpy as np
import scipy.sparse

from clis_modules.core.features import RbfGrid, uniform_centers
from clis_modules.core.localization import LocalizationParams, MarkovLocalizer
from clis_modules.core.modules import PolicyParams, ValueParams
from clis_modules.core.plugin import FeatureModel, ModuleContext, ModulePlugin, Percept

__all__ = ['PLACE_FEATURES', 'PlaceFeatureParams', 'PlaceParams', 'Place', 'PlaceModel',
           'place_projection']

#: ``place.features.kind``: the belief itself, or projected onto RBFs over the pose.
PLACE_FEATURES = ('belief', 'rbf')


@dataclass(frozen=True)
class PlaceFeatureParams:
    """What the place module's linear value (1) and policy (10) read of its belief (section
    ``place.features``; the paper is silent beyond "b_pl,j(x) denotes the robot's belief")."""

    kind: str = param(choices=PLACE_FEATURES,
                      doc="'belief' = the belief over the grid cells itself (paper III-D); "
                          "'rbf' = the belief projected onto Gaussian RBFs over (x, y, theta), "
                          'b_k = sum_cells belief(cell) phi_k(cell), which generalise across '
                          'neighbouring cells (our choice)')
    n_xy: int = param(1, 100, doc="RBF centres per axis of the floor ('rbf')")
    n_theta: int = param(1, 100, doc="RBF centres over the heading ('rbf')")
    phi_xy: float = param(1e-6, 100.0, doc="RBF width over x and y [m^2] ('rbf')")
    phi_theta: float = param(1e-6, 100.0, doc="RBF width over the heading [rad^2] ('rbf')")


@dataclass(frozen=True)
class PlaceParams:
    """The place-based module M_pl (section ``place``, paper III-D)."""

    period: float = param(0.01, 60.0, doc='decision period tau_pl [s]')
    localization: LocalizationParams = param(doc='section place.localization')
    features: PlaceFeatureParams = param(doc='section place.features')
    value: ValueParams = param(doc='section place.value')
    policy: PolicyParams = param(doc='section place.policy')


class Place(ModulePlugin):
    """Plug-in ``place`` (module docstring)."""

    Params = PlaceParams
    sensors = ('camera', 'wheels')
    learned = True
    topics = {'belief': 'nav_msgs/msg/OccupancyGrid'}

    def model(self, prm: PlaceParams, ctx: ModuleContext) -> PlaceModel:
        loc = MarkovLocalizer(prm.localization, ctx.landmarks_xy, ctx.floor, ctx.boxes)
        P = place_projection(loc, prm.features) if prm.features.kind == 'rbf' else None  # noqa: N806
        return PlaceModel(loc, P)


class PlaceModel(FeatureModel):
    """The place module's state, its localizer's belief, and the features of that belief
    (module docstring).

    Parameters
    ----------
    loc : MarkovLocalizer
        The state.
    P : scipy.sparse.csr_matrix, optional
        The projection of the ``rbf`` features (:func:`place_projection`); None: the belief.
    """

    def __init__(self, loc: MarkovLocalizer, P: scipy.sparse.csr_matrix | None) -> None:  # noqa: N803
        self.loc, self.P = loc, P
        self.state = loc
        super().__init__(loc.size if P is None else P.shape[0])

    def of(self, belief: np.ndarray) -> np.ndarray:
        """The features of any belief: itself, or ``P b`` (``features.kind``)."""
        return belief.copy() if self.P is None else self.P @ belief

    def features(self, percept: Percept) -> np.ndarray:
        return self.of(self.loc.belief)

    def reset(self) -> None:
        self.loc.reset()                            # a uniform belief

    def motion(self, dx: float, dy: float, dtheta: float) -> None:
        self.loc.predict(dx, dy, dtheta)            # b(x') <- sum_x Pr(x' | x, u) b(x)

    def sense(self, percept: Percept) -> None:
        self.loc.update(percept.landmark_bearings)  # paper III-D: b(x) <- eta Pr(s | x) b(x)

    def peek(self, odometry: tuple[float, float, float] | None,
             percept: Percept) -> np.ndarray:
        return self.of(self.loc.peek(odometry, percept.landmark_bearings))

    def at_pose(self, x: float, y: float, heading: float) -> None:
        onehot = np.zeros(self.loc.shape)
        onehot[self.loc.cell_of(x, y, heading)] = 1.0
        self.loc.set_belief(onehot)

    def display(self) -> tuple[np.ndarray, float, tuple[float, float]]:
        return self.loc.belief_grid, self.loc.cell, self.loc.origin


def place_projection(loc: MarkovLocalizer, fp: PlaceFeatureParams) -> scipy.sparse.csr_matrix:
    """``P`` of the  ``rbf`` features, shape (n_xy^2 n_theta, cells): column
    ``c`` the normalised RBFs at the centre pose of cell ``c`` (the belief's flat order,
    ``(heading, x, y)``)."""
    x0, x1 = loc.xs[0] - 0.5 * loc.cell, loc.xs[-1] + 0.5 * loc.cell
    y0, y1 = loc.ys[0] - 0.5 * loc.cell, loc.ys[-1] + 0.5 * loc.cell
    # centres in the middles of n equal bins of each axis (as for a periodic input)
    grid = RbfGrid([x0 + (x1 - x0) * (np.arange(fp.n_xy) + 0.5) / fp.n_xy,
                    y0 + (y1 - y0) * (np.arange(fp.n_xy) + 0.5) / fp.n_xy,
                    uniform_centers(-math.pi, math.pi, fp.n_theta, True)],
                   [fp.phi_xy, fp.phi_xy, fp.phi_theta], [False, False, True], normalize=True)
    th, gx, gy = np.meshgrid(loc.thetas, loc.xs, loc.ys, indexing='ij')
    poses = np.stack([gx.ravel(), gy.ravel(), th.ravel()], axis=1)    # flat order of belief
    P = grid.batch(poses)[:, :-1].T  # noqa: N806
    # sparse: activations below 1e-4 of a cell's mass dropped, each column renormalised to 1
    P[P < 1e-4] = 0.0
    return scipy.sparse.csr_matrix(P / P.sum(axis=0, keepdims=True))
