"""A module's proposal: what a module decides and the arbiter, the lockstep and the learner read.

Made by :class:`clis_modules.core.decider.Decider` (the headless runner's and the module nodes'
decisions), published by the module nodes (:func:`clis_modules.conversions.proposal_msg`),
selected from by :class:`clis_modules.core.arbiter.Arbiter`, and recorded for learning by
:mod:`clis_learner.core.intake`. Its own module so that they all depend on it and not on each
other.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ['Proposal']


class Proposal(NamedTuple):
    """A module's decision at time ``t`` (what a module node publishes; immutable, a named
    tuple as :class:`~clis_modules.core.decider.Percept`: one per decision).

    Attributes
    ----------
    module : str
        The module's name.
    t : float
        Time of the sensor readings the decision used [s]: the decision time ``t_l``.
    b : np.ndarray, shape (n,)
        Features ``b_i(x(t_l))``.
    u : np.ndarray, shape (2,)
        Proposed ``(v_left, v_right)`` [m/s] drawn from (10), not clipped to the speed limit
        (the learner's densities are of this action).
    mean : np.ndarray, shape (2,)
        Policy mean ``v_max W_i b`` [m/s].
    sigma : float
        Policy standard deviation at ``b`` [m/s].
    value : float
        ``V_i(x(t_l)) = w_i^T b`` (1)(2).
    version : int
        Version of the parameters the decision used (learned episodes; 0 = initial).
    uncertainty : float
        ``u_i(x(t_l))`` of the exploration bonus (:func:`clis_modules.core.arbiter.uncertainty`)
        at the episode's first decision, whose values the start draw reads; 0 at the others
        and when the module keeps no selection counts (``arbiter.bonus = 0``).
    """

    module: str
    t: float
    b: np.ndarray
    u: np.ndarray
    mean: np.ndarray
    sigma: float
    value: float
    version: int = 0
    uncertainty: float = 0.0
