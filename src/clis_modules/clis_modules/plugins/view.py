"""The view-based module M_vi (paper III-C): what the robot sees now.

Features: Gaussian RBFs on the grid ``n_theta x n_dist`` over ``(theta_d, d_o)``, the
destination's bearing (periodic) and the distance to the nearest obstacle (the smallest IR
ray), plus the *not visible* feature; ``b = e_n`` when the destination is not seen, whatever
``d_o`` is (paper III-C). Value (1)(2) and policy (10) learned by (8) and (9).

With ``lost_side`` (ours, beyond the paper; a robot profile with a forward camera turns it on,
docs/robots.md), the *not visible* feature is three: the destination *not seen yet* in the
episode, *last seen on the left* and *last seen on the right* (the sign of its bearing at the
module's last decision that saw it). The Cyber Rodent's omni-directional camera loses the
destination only behind an obstacle; a forward camera loses it at the edge of its field of
view, and the edge it left by tells where it is. The side is the module's state: forgotten at
an episode's start (``reset``), set at each decision that sees the destination (``sense``).
"""

from __future__ import annotations

import math

from clis_base.params import dataclass, param
import numpy as np

from clis_modules.core.features import RbfGrid, uniform_centers
from clis_modules.core.modules import PolicyParams, ValueParams
from clis_modules.core.plugin import FeatureModel, ModuleContext, ModulePlugin, Percept

__all__ = ['ViewParams', 'View', 'ViewModel', 'LostSideViewModel']


@dataclass(frozen=True)
class ViewParams:
    """The view-based module M_vi (section ``view``, paper III-C)."""

    period: float = param(0.01, 60.0, doc='decision period tau_vi [s]')
    n_theta: int = param(1, 100, doc='number of RBF centres over theta_d')
    n_dist: int = param(1, 100, doc='number of RBF centres over d_o')
    phi_theta: float = param(1e-6, 100.0, doc='RBF width over theta_d [rad^2]')
    phi_dist: float = param(1e-8, 100.0, doc='RBF width over d_o [m^2]')
    d_max: float = param(0.01, 10.0, doc='largest d_o centre [m] (the IR range)')
    normalize: bool = param(doc='normalise the RBFs to sum 1')
    lost_side: bool = param(off=False, doc='split the not visible feature by the side where '
                            'the destination was last seen: not yet, left, right (ours)')
    value: ValueParams = param(doc='section view.value')
    policy: PolicyParams = param(doc='section view.policy')


class View(ModulePlugin):
    """Plug-in ``view`` (module docstring)."""

    Params = ViewParams
    sensors = ('camera', 'ir')
    learned = True

    def model(self, prm: ViewParams, ctx: ModuleContext) -> ViewModel:
        return LostSideViewModel(prm) if prm.lost_side else ViewModel(prm)


class ViewModel(FeatureModel):
    """The view module's features (module docstring): ``n_theta n_dist`` RBFs and the *not
    visible* feature, ``b = e_n`` where the destination is not seen; no state."""

    def __init__(self, prm: ViewParams, extra: int = 0) -> None:
        self.grid = RbfGrid([uniform_centers(-math.pi, math.pi, prm.n_theta, periodic=True),
                             uniform_centers(0.0, prm.d_max, prm.n_dist, False)],
                            [prm.phi_theta, prm.phi_dist], [True, False], prm.normalize)
        super().__init__(self.grid.n + extra)

    def features(self, percept: Percept) -> np.ndarray:
        # not visible -> e_n whatever d_o is (paper III-C)
        dest = percept.dest_bearing
        return self.grid.at(dest, percept.d_o if math.isfinite(dest) else 0.0)


class LostSideViewModel(ViewModel):
    """``lost_side`` (module docstring): the RBFs, then three *not visible* features ``(not
    yet, left, right)``, ``n = n_theta n_dist + 3``.

    Attributes
    ----------
    side : int
        Where the destination was last seen in the episode: 0 not yet, 1 on the left
        (bearing >= 0), 2 on the right.
    """

    def __init__(self, prm: ViewParams) -> None:
        super().__init__(prm, extra=2)
        self.side = 0

    def features(self, percept: Percept) -> np.ndarray:
        out = np.zeros(self.n)
        if math.isfinite(percept.dest_bearing):
            out[:self.grid.n] = super().features(percept)
        else:
            # not visible -> the feature of the side it was last seen on (not yet, left, right)
            out[self.grid.n - 1 + self.side] = 1.0
        return out

    def reset(self) -> None:
        self.side = 0

    def sense(self, percept: Percept) -> None:
        # the side at the last decision that saw it. peek needs no override: the features read
        # the side only where the destination is not seen, where sense leaves it as it is
        dest = percept.dest_bearing
        if math.isfinite(dest):
            self.side = 1 if dest >= 0.0 else 2
