"""The view-based module M_vi (paper III-C): what the robot sees now.

Features: Gaussian RBFs on the grid ``n_theta x n_dist`` over ``(theta_d, d_o)``, the
destination's bearing (periodic) and the distance to the nearest obstacle (the smallest IR
ray), plus the *not visible* feature; ``b = e_n`` when the destination is not seen, whatever
``d_o`` is (paper III-C). Value (1)(2) and policy (10) learned by (8) and (9).
"""

from __future__ import annotations

import math

from clis_base.params import dataclass, param
import numpy as np

from clis_modules.core.features import RbfGrid, uniform_centers
from clis_modules.core.modules import PolicyParams, ValueParams
from clis_modules.core.plugin import FeatureModel, ModuleContext, ModulePlugin, Percept

__all__ = ['ViewParams', 'View', 'ViewModel']


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
    value: ValueParams = param(doc='section view.value')
    policy: PolicyParams = param(doc='section view.policy')


class View(ModulePlugin):
    """Plug-in ``view`` (module docstring)."""

    Params = ViewParams
    sensors = ('camera', 'ir')
    learned = True

    def model(self, prm: ViewParams, ctx: ModuleContext) -> ViewModel:
        return ViewModel(prm)


class ViewModel(FeatureModel):
    """The view module's features (module docstring); no state."""

    def __init__(self, prm: ViewParams) -> None:
        self.grid = RbfGrid([uniform_centers(-math.pi, math.pi, prm.n_theta, periodic=True),
                             uniform_centers(0.0, prm.d_max, prm.n_dist, False)],
                            [prm.phi_theta, prm.phi_dist], [True, False], prm.normalize)
        super().__init__(self.grid.n)

    def features(self, percept: Percept) -> np.ndarray:
        # not visible -> e_n whatever d_o is (paper III-C)
        dest = percept.dest_bearing
        return self.grid.at(dest, percept.d_o if math.isfinite(dest) else 0.0)
