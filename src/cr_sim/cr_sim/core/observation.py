"""What the robot senses at one instant: :class:`Observation`.

Made by the simulator (:class:`cr_sim.core.sim.Simulator`) and by the real robot's episode
logic (:mod:`cr_bridge.core.episode`), read by the wander policy (:mod:`cr_sim.core.wander`),
the Gymnasium env and the modules: its own module, so that they depend on it and not on the
simulator.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

__all__ = ['Observation']


@dataclass(frozen=True, slots=True)
class Observation:
    """What the robot senses at time ``t`` (arrays are read-only).

    Attributes
    ----------
    t : float
        Time since reset [s].
    ir : np.ndarray, shape (n_ir,)
        Distance from the body surface to the first wall/obstacle along each beam [m], in
        ``[0, ir_range]``; ``ir_range`` when nothing is within range.
    dest_bearing : float
        Bearing of the destination relative to the heading [rad], in (-pi, pi], counter-
        clockwise positive; ``nan`` when not seen.
    landmark_bearings : np.ndarray, shape (n_landmarks,)
        Same for each landmark, in arena-file order.
    wheels : np.ndarray, shape (2,)
        Executed ``(v_left, v_right)`` of the last step [m/s] (odometry); zeros after reset.
    """

    t: float
    ir: np.ndarray
    dest_bearing: float
    landmark_bearings: np.ndarray
    wheels: np.ndarray

    @property
    def d_o(self) -> float:
        """Distance to the nearest obstacle seen by the IR: ``min(ir)`` [m]."""
        return float(self.ir.min())

    @property
    def dest_visible(self) -> bool:
        """Whether the destination is seen."""
        return not math.isnan(self.dest_bearing)

    @property
    def landmarks_visible(self) -> np.ndarray:
        """Which landmarks are seen, shape (n_landmarks,), bool."""
        return ~np.isnan(self.landmark_bearings)
