"""What ``clis run --robot ros`` writes for a robot of another size than the Cyber Rodent.

A profile's ``arena`` section scales the layout to the robot (the Husky's 10 m for the Cyber
Rodent's 3 m, a scale ``s = 10 / 3``). The robot adapter scales it itself; the graph's nodes map
the arena from a file (``graph.arena_file``: the place module's grid and landmarks), so the run
writes the scaled layout to ``OUT/arena.yaml``, and a parameter file ``OUT/robot_params.yaml``
in which the model's lengths follow the robot (the same model on a floor ``s`` times larger,
driven in the same time; the values of the run's preset and ``--params`` scaled):

=================================================  ==============================================
key                                                on the robot
=================================================  ==============================================
``localization.cell_size``, ``trans_noise_min``    ``x s`` (the same grid over a larger floor)
``features.phi_xy`` (a squared length)             ``x s^2``
``d_max`` (the distance features' range)           the profile's ``scan.range_max``, with
                                                   ``phi_dist`` ``x (range_max / d_max)^2``
``common.d_react`` (distance between decisions)    ``x s``: the modules' speed limits
                                                   ``v_max,i = d_react / tau_i`` grow with it
``common.v_wheel_max`` (their cap)                 the robot's wheel limit (``body.v_wheel_max``,
                                                   or ``body.v_max`` when it has none)
every wheel-speed std (``sigma``,                  ``x s`` (exploration in proportion to the
``sigma_blind``, ``sigma_min``, ``sigma_max``)     speeds)
``common.epsilon`` of (7) (a density of wheel      ``/ s^2`` (the densities it is added to scale
speeds)                                            so): (7)'s ratios are unchanged
=================================================  ==============================================

And whatever the robot's size, a forward camera (``camera.model: pinhole``) turns on the view
instances' ``lost_side`` (three *not visible* features, by the side the destination was last
seen on: :mod:`clis_modules.plugins.view`) where the run's ``--params`` do not set it: such a
camera loses the destination at the edges of its field of view, the omni-directional camera of
the paper's robot only behind obstacles.

The robot then moves as the Cyber Rodent would on the layout at the robot's size: its wheel
speeds ``s`` times, its yaw rates about the same where its wheel base is in proportion (the
Husky's 0.555 m; the Cyber Rodent's 0.16 m times ``s``, 0.53 m). The improved preset's steps
are in units of ``sigma`` (``policy_step: scaled``, ``max_mean_step``) and follow; the paper's
policy step (9) on the mean in m/s does not (the paper preset on a larger robot learns its
policy at another rate).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from clis_learner.core.config import ClisParams, load_clis_params
from cr_sim.core.arena import Arena, arena_data, load_arena, scaled_arena
from cr_sim.core.profile import RobotProfile, load_profile
import yaml

from clis_app import files

__all__ = ['ARENA_FILE', 'PARAMS_FILE', 'robot_files', 'robot_arena', 'robot_params',
           'module_params']

ARENA_FILE = 'arena.yaml'
PARAMS_FILE = 'robot_params.yaml'


def robot_files(profile: str, out: Path, write: bool = True,
                overrides: Mapping[str, Any] | None = None) -> tuple[str, Path | None]:
    """``(arena_file, params_file)`` of a run on the robot of ``profile`` into ``out``: the
    profile's own arena file when it is not scaled, else the scaled one; the parameter file,
    or None when no key follows the robot (both written with ``write``). ``overrides``: the
    run's CLIS keys (its preset and ``--params``, dotted), the values that are scaled and
    the keys that the run sets itself."""
    robot, arena, scale = _layout(profile)
    keys = robot_params(profile, overrides)
    arena_file = (str(robot.arena.path()) if robot.arena.file else '') if scale == 1.0 \
        else out / ARENA_FILE
    params_file = out / PARAMS_FILE if keys else None
    if write and scale != 1.0:
        files.write_text(arena_file, yaml.safe_dump(arena_data(scaled_arena(arena, scale)),
                                                     sort_keys=False))
    if write and keys:
        files.write_text(params_file, yaml.safe_dump({'/**': {'ros__parameters': keys}}))
    return str(arena_file), params_file


def _layout(profile: str) -> tuple[RobotProfile, Arena, float]:
    """The robot of ``profile``, its arena file's layout and the scale to the robot's size."""
    robot = load_profile(profile)
    arena = load_arena(robot.arena.path(), robot_radius=0.0)
    return robot, arena, robot.arena.scale(arena.size)


def robot_arena(profile: str) -> Arena:
    """The layout at the size of the robot of ``profile`` (what ``OUT/arena.yaml`` holds)."""
    _, arena, scale = _layout(profile)
    return arena if scale == 1.0 else scaled_arena(arena, scale)


def robot_params(profile: str, overrides: Mapping[str, Any] | None = None) -> dict:
    """The CLIS keys that follow the robot of ``profile`` (module docstring), nested by
    section; empty for a robot at the layout's size with an omni-directional camera.
    ``overrides``: as :func:`robot_files`."""
    robot, _, scale = _layout(profile)
    given = dict(overrides or {})
    clis = load_clis_params(overrides=given or None)
    body = robot.body
    out = {} if scale == 1.0 else module_params(clis, scale, robot.scan.range_max,
                                                 body.v_wheel_max or body.v_max)
    if robot.camera.model == 'pinhole':              # a forward camera
        for name, plugin, prm in clis.instances:    # unless set: on the instance, or on the
            if hasattr(prm, 'lost_side') and not {  # plug-in's section it inherits from
                    f'{name}.lost_side', f'{plugin}.lost_side'} & given.keys():
                out.setdefault(name, {})['lost_side'] = True
    return out


def module_params(clis: ClisParams, scale: float, range_max: float, wheel_limit: float
                  ) -> dict:
    """The keys of ``clis`` that follow a robot whose arena is ``scale`` times the layout's,
    whose scan reads up to ``range_max`` [m] and whose wheels go up to ``wheel_limit`` [m/s]
    (module docstring), nested by section."""
    c = clis.common
    out: dict = {'common': {'d_react': c.d_react * scale, 'v_wheel_max': wheel_limit,
                            'epsilon': c.epsilon / scale ** 2}}
    for name, _, prm in clis.instances:
        keys: dict = {}
        loc = getattr(prm, 'localization', None)
        if loc is not None:
            keys['localization'] = {'cell_size': loc.cell_size * scale,
                                    'trans_noise_min': loc.trans_noise_min * scale}
        features = getattr(prm, 'features', None)
        if features is not None and hasattr(features, 'phi_xy'):
            keys['features'] = {'phi_xy': features.phi_xy * scale ** 2}
        d_max = getattr(prm, 'd_max', None)
        if d_max and range_max != d_max:
            r = range_max / d_max
            keys.update({'d_max': range_max, 'phi_dist': prm.phi_dist * r * r})
        for key in ('sigma', 'sigma_blind'):            # a fixed policy's stds
            if hasattr(prm, key):
                keys[key] = getattr(prm, key) * scale
        policy = getattr(prm, 'policy', None)
        if policy is not None:
            keys['policy'] = {k: getattr(policy, k) * scale
                              for k in ('sigma', 'sigma_min', 'sigma_max')}
        if keys:
            out[name] = keys
    return out
