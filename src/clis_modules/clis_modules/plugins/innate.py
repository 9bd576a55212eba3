"""The innate module M_in (paper III-B): a fixed, hand-made policy to the destination.

Features: ``n_rbf`` periodic Gaussian RBFs over the destination's bearing ``theta_d``, plus the
*not visible* feature (:class:`~clis_modules.core.features.RbfGrid`). Its value (1)(2) is
learned by (8); its policy is not learned.

The policy (paper III-B: "moves to the destination directly ... if the destination is not
observed, it generates random action") is hand-made as a target mean

    s = clip(theta_d / turn_angle, -1, 1),   a = forward (1 - |s|)
    mu*(theta_d) = v_max (a - s,  a + s)                          (v_left, v_right)

(straight ahead at ``forward v_max`` when aligned, the wheel-speed difference proportional to
the bearing, turning in place at full speed beyond ``turn_angle``; ``|mu*| <= v_max``. Since
``v_max tau = d_react``, the heading change per decision, ``2 s d_react / wheel_base``, is the
same whatever the period: about 1.2 theta_d with the defaults, a stable correction), written in
the module's own features: ``W_in`` is the least-squares fit of ``mu* / v_max`` on the RBFs over
a dense grid of theta_d, and the *not visible* column is the blind mean ``blind_forward v_max``
on both wheels, with the wider ``sigma_blind``. So the innate module is the same
linear-Gaussian object as the learned ones (same density and sampling code), only never
updated by (9).
"""

from __future__ import annotations

import math

from clis_base.params import dataclass, param
import numpy as np
from numpy.typing import ArrayLike

from clis_modules.core.features import RbfGrid, uniform_centers
from clis_modules.core.modules import ValueParams
from clis_modules.core.plugin import FeatureModel, ModuleContext, ModulePlugin, Percept

__all__ = ['InnateParams', 'Innate', 'InnateModel', 'innate_target_mean']


@dataclass(frozen=True)
class InnateParams:
    """The innate module M_in (section ``innate``, paper III-B)."""

    period: float = param(0.01, 60.0, doc='decision period tau_in [s]')
    n_rbf: int = param(1, 1000, doc='number of RBFs over theta_d')
    phi: float = param(1e-6, 100.0, doc='RBF width phi_in [rad^2]')
    normalize: bool = param(doc='normalise the RBFs to sum 1')
    value: ValueParams = param(doc='section innate.value')
    forward: float = param(0.0, 1.0, doc='forward speed when aligned, fraction of v_max')
    turn_angle_deg: float = param(1.0, 180.0, doc='bearing beyond which it turns in place [deg]')
    sigma: float = param(1e-3, 5.0, doc='std of each wheel when the destination is seen [m/s]')
    blind_forward: float = param(-1.0, 1.0, doc='mean wheel speed when not seen, x v_max')
    sigma_blind: float = param(1e-3, 5.0, doc='std of each wheel when not seen [m/s]')


def innate_target_mean(theta_d: ArrayLike, forward: float, turn_angle: float) -> np.ndarray:
    """Hand-made innate mean ``mu* / v_max`` (module docstring), shape (N, 2).

    Parameters
    ----------
    theta_d : array_like, shape (N,)
        Bearing of the destination [rad], counter-clockwise positive.
    forward : float
        Forward wheel speed when aligned, as a fraction of ``v_max``.
    turn_angle : float
        Bearing [rad] beyond which the robot turns in place.
    """
    s = np.clip(np.asarray(theta_d, dtype=np.float64) / turn_angle, -1.0, 1.0)
    a = forward * (1.0 - np.abs(s))
    return np.stack([a - s, a + s], axis=-1)


class Innate(ModulePlugin):
    """Plug-in ``innate`` (module docstring)."""

    Params = InnateParams
    sensors = ('camera',)
    learned = False

    def model(self, prm: InnateParams, ctx: ModuleContext) -> InnateModel:
        return InnateModel(prm)


class InnateModel(FeatureModel):
    """The innate module's features and hand-made policy (module docstring); no state."""

    def __init__(self, prm: InnateParams) -> None:
        self.grid = RbfGrid([uniform_centers(-math.pi, math.pi, prm.n_rbf, periodic=True)],
                            [prm.phi], [True], prm.normalize)
        # hand-made policy written in the module's features: least squares over a dense grid
        theta = np.linspace(-math.pi, math.pi, 721)
        b = self.grid.batch(theta[:, None])[:, :-1]
        target = innate_target_mean(theta, prm.forward, math.radians(prm.turn_angle_deg))
        fit, *_ = np.linalg.lstsq(b, target, rcond=None)                   # (n_rbf, 2)
        W = np.empty((2, self.grid.n))  # noqa: N806 - the paper's W
        W[:, :-1] = fit.T
        W[:, -1] = prm.blind_forward
        super().__init__(self.grid.n, W, sigma=prm.sigma, sigma_blind=prm.sigma_blind)

    def features(self, percept: Percept) -> np.ndarray:
        return self.grid.at(percept.dest_bearing)
