"""Message conversions of the CLIS graph: the one place where module, arbiter and learner values
meet ROS types (the robot interface itself is :mod:`cr_sim.conversions`).

Standard messages only (custom interfaces cannot be built from the ROS 2 wheels). A record with
a time stamp, a few named scalars and one or two float vectors is a ``sensor_msgs/JointState``
whose ``name[k]`` names ``position[k]``; ``header.frame_id`` names the module. The layouts
(docs/graph.md, topic table):

=====================  ===========================================================================
topic                  sensor_msgs/JointState layout
=====================  ===========================================================================
``<module>/proposal``  stamp = time of the sensor readings the decision used (decision time
                       ``t_l``); frame_id = module; name = :data:`PROPOSAL_FIELDS`, position =
                       their values (sampled wheel command and policy mean [m/s], sigma [m/s],
                       V_i(x), parameter version, the clock time the decision was made);
                       velocity = the features ``b_i(x)`` (n)
``<module>/params``    stamp = time of the update; frame_id = module; name = :data:`PARAMS_FIELDS`,
                       position = (version, sigma, n); velocity = ``w_i`` (n); effort = ``W_i``
                       row-major (2 n: left wheel row, then right)
``arbiter/selection``  stamp = time of the draw; frame_id = acting module; name = modules,
                       position = ``Pr(i | x)`` of (3), velocity = ``V_i`` used
``arbiter/action``     stamp = time from which the command is in force; frame_id = acting module
                       ('' = stop); name = wheels, velocity = the acting module's proposal
                       (not clipped) [m/s]
=====================  ===========================================================================

``place/belief`` is a ``nav_msgs/OccupancyGrid``: the belief marginalised over heading, scaled
so that the most probable cell is 100.
"""

from __future__ import annotations

from array import array
from collections.abc import Sequence

from cr_sim.conversions import WHEEL_NAMES, from_time, to_time
from nav_msgs.msg import OccupancyGrid
import numpy as np
from numpy.typing import ArrayLike
from sensor_msgs.msg import JointState

from clis_modules.core.proposal import Proposal

__all__ = ['PROPOSAL_FIELDS', 'PARAMS_FIELDS', 'OBSERVATION_FIELDS', 'observation_msg',
           'observation_from_msg', 'proposal_msg', 'proposal_from_msg',
           'params_msg', 'params_from_msg', 'selection_msg', 'selection_from_msg',
           'action_msg', 'action_from_msg', 'belief_msg']

#: Named scalars of a proposal (``position``), in order.
PROPOSAL_FIELDS = ('u_left', 'u_right', 'mean_left', 'mean_right', 'sigma', 'value', 'version',
                   'decided_at')
#: Named scalars of a parameter message (``position``), in order.
PARAMS_FIELDS = ('version', 'sigma', 'n')


def _f64(values: ArrayLike) -> array:
    """A float64 ``array.array`` (what rclpy stores sequences as; fast from numpy)."""
    out = array('d')
    out.frombytes(np.ascontiguousarray(values, dtype=np.float64).tobytes())
    return out


def _np(values: Sequence[float]) -> np.ndarray:
    """A message's float64 sequence as a numpy array (a copy)."""
    if isinstance(values, array):
        return np.frombuffer(values, dtype=np.float64).copy()
    return np.asarray(values, dtype=np.float64)


def _check(msg: JointState, fields: Sequence[str], what: str) -> None:
    if tuple(msg.name) != tuple(fields):
        raise ValueError(f'{what}: expected name = {list(fields)}, got {list(msg.name)}')


def proposal_msg(p: Proposal, decided_at: float) -> JointState:
    """A module's :class:`~clis_modules.core.proposal.Proposal`, decided at clock time
    ``decided_at`` [s]."""
    msg = JointState(name=list(PROPOSAL_FIELDS))
    msg.header.stamp, msg.header.frame_id = to_time(p.t), p.module
    msg.position = _f64([p.u[0], p.u[1], p.mean[0], p.mean[1], p.sigma, p.value, p.version,
                         decided_at])
    msg.velocity = _f64(p.b)
    return msg


def proposal_from_msg(msg: JointState) -> Proposal:
    """Inverse of :func:`proposal_msg` (``decided_at`` is dropped); raises ValueError on a
    message of another layout."""
    _check(msg, PROPOSAL_FIELDS, 'proposal')
    v = _np(msg.position)
    return Proposal(msg.header.frame_id, from_time(msg.header.stamp), _np(msg.velocity),
                    v[0:2].copy(), v[2:4].copy(), float(v[4]), float(v[5]), int(v[6]))


#: ``name`` of an observation message (its features are in ``velocity``).
OBSERVATION_FIELDS = ('observation',)


def observation_msg(module: str, t: float, b: ArrayLike) -> JointState:
    """A module's features ``b`` at ``t``, an instant at which it did not decide (the
    behaviour's state of (6): :meth:`~clis_modules.core.decider.Decider.observe`)."""
    msg = JointState(name=list(OBSERVATION_FIELDS))
    msg.header.stamp, msg.header.frame_id = to_time(t), module
    msg.velocity = _f64(np.asarray(b, dtype=np.float64))
    return msg


def observation_from_msg(msg: JointState) -> tuple[str, float, np.ndarray]:
    """Inverse of :func:`observation_msg`: ``(module, t, b)``; ValueError on another
    layout."""
    _check(msg, OBSERVATION_FIELDS, 'observation')
    return msg.header.frame_id, from_time(msg.header.stamp), _np(msg.velocity)


def params_msg(module: str, w: ArrayLike, W: ArrayLike, sigma: float,  # noqa: N803
               version: int, t: float) -> JointState:
    """A module's learned parameters: value weights ``w`` (n,), policy weights ``W`` (2, n)."""
    w = np.asarray(w, dtype=np.float64)
    msg = JointState(name=list(PARAMS_FIELDS))
    msg.header.stamp, msg.header.frame_id = to_time(t), module
    msg.position = _f64([version, sigma, w.size])
    msg.velocity = _f64(w)
    msg.effort = _f64(np.asarray(W, dtype=np.float64).reshape(-1))
    return msg


def params_from_msg(msg: JointState) -> tuple[str, np.ndarray, np.ndarray, float, int]:
    """``(module, w (n,), W (2, n), sigma, version)``; ValueError if the sizes disagree."""
    _check(msg, PARAMS_FIELDS, 'params')
    version, sigma, n = _np(msg.position)
    w, flat = _np(msg.velocity), _np(msg.effort)
    if w.size != int(n) or flat.size != 2 * int(n):
        raise ValueError(f'params of {msg.header.frame_id}: n = {int(n)} but {w.size} value '
                         f'and {flat.size} policy weights')
    return msg.header.frame_id, w, flat.reshape(2, -1), float(sigma), int(version)


def selection_msg(names: Sequence[str], probs: ArrayLike, values: ArrayLike, acting: str,
                  t: float) -> JointState:
    """A draw of the arbiter: ``Pr(i | x)`` of (3) and the values it used."""
    msg = JointState(name=list(names), position=_f64(probs), velocity=_f64(values))
    msg.header.stamp, msg.header.frame_id = to_time(t), acting
    return msg


def selection_from_msg(msg: JointState) -> tuple[float, str, dict[str, float],
                                                 dict[str, float]]:
    """``(t, acting, {module: Pr}, {module: V})``."""
    return (from_time(msg.header.stamp), msg.header.frame_id,
            dict(zip(msg.name, _np(msg.position))), dict(zip(msg.name, _np(msg.velocity))))


def action_msg(t: float, u: ArrayLike, acting: str) -> JointState:
    """The command in force from ``t``: the acting module's proposal ``u`` (not clipped);
    ``acting = ''`` for a stop."""
    msg = JointState(name=list(WHEEL_NAMES), velocity=_f64(u))
    msg.header.stamp, msg.header.frame_id = to_time(t), acting
    return msg


def action_from_msg(msg: JointState) -> tuple[float, np.ndarray, str]:
    """``(t, u (2,), acting)``."""
    return from_time(msg.header.stamp), _np(msg.velocity), msg.header.frame_id


def belief_msg(belief_grid: np.ndarray, cell: float, origin: tuple[float, float], t: float,
               frame: str) -> OccupancyGrid:
    """The place module's belief ``(n_headings, nx, ny)`` marginalised over heading, as an
    occupancy grid scaled to 0..100 (100 = the most probable cell)."""
    marginal = np.asarray(belief_grid).sum(axis=0)                  # (nx, ny)
    top = marginal.max()
    scaled = np.zeros_like(marginal) if top <= 0 else 100.0 * marginal / top
    msg = OccupancyGrid()
    msg.header.stamp, msg.header.frame_id = to_time(t), frame
    msg.info.map_load_time = msg.header.stamp
    msg.info.resolution = float(cell)
    msg.info.width, msg.info.height = int(marginal.shape[0]), int(marginal.shape[1])
    msg.info.origin.position.x, msg.info.origin.position.y = (float(o) for o in origin)
    msg.info.origin.orientation.w = 1.0
    # row-major over y (rows) then x (columns)
    data = np.rint(scaled.T).astype(np.int8).reshape(-1)
    msg.data = array('b', data.tobytes())
    return msg
