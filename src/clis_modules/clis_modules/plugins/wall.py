"""The wall module (ours, beyond the paper): every IR ray and the destination's bearing.

An example of a module of one's own (docs/modules.md), which the view module's single
``d_o = min(ir)`` cannot be: it knows *where* the obstacle is. Features, concatenated:

- per IR ray ``r`` (7, in the robot's ray order), ``n_dist`` Gaussian RBFs over its reading
  ``ir_r`` in ``[0, d_max]``, normalised to sum 1 per ray;
- ``n_theta`` periodic RBFs over ``theta_d`` plus the *not visible* feature, normalised;

each block scaled by ``1 / (n_rays + 1)``, so ``b`` sums to 1 and ``V = v_init`` everywhere at
the start. Value (1)(2) and policy (10) learned by (8) and (9) like any module's; decision
period 750 ms (between the view module's and the place module's).
"""

from __future__ import annotations

import math

from clis_base.params import dataclass, param
import numpy as np

from clis_modules.core.features import RbfGrid, uniform_centers
from clis_modules.core.modules import PolicyParams, ValueParams
from clis_modules.core.plugin import FeatureModel, ModuleContext, ModulePlugin, Percept

__all__ = ['WallParams', 'Wall', 'WallModel']


@dataclass(frozen=True)
class WallParams:
    """The wall module (section ``wall``, module docstring)."""

    period: float = param(0.01, 60.0, doc='decision period [s]')
    n_rays: int = param(1, 64, doc='IR rays read (the robot has 7)')
    n_dist: int = param(1, 100, doc='RBF centres over each ray reading')
    phi_dist: float = param(1e-8, 100.0, doc='RBF width over a ray reading [m^2]')
    d_max: float = param(0.01, 10.0, doc='largest centre over a ray reading [m] (IR range)')
    n_theta: int = param(1, 100, doc='RBF centres over theta_d')
    phi_theta: float = param(1e-6, 100.0, doc='RBF width over theta_d [rad^2]')
    value: ValueParams = param(doc='section wall.value')
    policy: PolicyParams = param(doc='section wall.policy')


class Wall(ModulePlugin):
    """Plug-in ``wall`` (module docstring)."""

    Params = WallParams
    sensors = ('camera', 'ir')
    learned = True

    def model(self, prm: WallParams, ctx: ModuleContext) -> WallModel:
        return WallModel(prm)


class WallModel(FeatureModel):
    """The wall module's features (module docstring); no state."""

    def __init__(self, prm: WallParams) -> None:
        self.centres = uniform_centers(0.0, prm.d_max, prm.n_dist, False)
        self.bearing = RbfGrid([uniform_centers(-math.pi, math.pi, prm.n_theta, periodic=True)],
                               [prm.phi_theta], [True], normalize=True)
        self.rays, self.n_dist = prm.n_rays, prm.n_dist
        self.phi_dist, self.d_max = prm.phi_dist, prm.d_max
        self.scale = 1.0 / (prm.n_rays + 1)
        super().__init__(prm.n_rays * prm.n_dist + self.bearing.n)

    def features(self, percept: Percept) -> np.ndarray:
        rays, centres = self.rays, self.centres
        b = np.empty(self.n)
        ir = np.full(rays, self.d_max) if percept.ir is None else np.asarray(percept.ir)[:rays]
        g = np.exp(-(ir[:, None] - centres[None, :]) ** 2 / self.phi_dist)  # (rays, n_dist)
        g /= np.maximum(g.sum(axis=1, keepdims=True), 1e-300)
        k = rays * self.n_dist
        b[:k] = self.scale * g.ravel()
        b[k:] = self.scale * self.bearing.at(percept.dest_bearing)
        return b
