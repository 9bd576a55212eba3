"""What ``clis run --robot ros`` writes for a robot of another size than the Cyber Rodent.

A profile's ``arena`` section scales the layout to the robot (the Husky's 10 m for the Cyber
Rodent's 3 m). The robot adapter scales it itself; the graph's nodes map the arena from a file
(``graph.arena_file``: the place module's grid and landmarks), so the run writes the scaled
layout to ``OUT/arena.yaml``, and a parameter file ``OUT/robot_params.yaml`` in which the
modules' features follow the robot: the place module's grid cells
(``localization.cell_size``) and its least position noise per motion update
(``trans_noise_min``) grow with the arena (the same grid of cells over a larger floor), and the
range of the distance features of the modules that read the IR rays (``d_max``, with the width
``phi_dist`` of their RBFs, a squared length) grows to the profile's ``scan.range_max``.
"""

from __future__ import annotations

from pathlib import Path

from clis_learner.core.config import load_clis_params
from cr_sim.core.arena import arena_data, load_arena, scaled_arena
from cr_sim.core.profile import load_profile
import yaml

from clis_app import files

__all__ = ['ARENA_FILE', 'PARAMS_FILE', 'robot_files']

ARENA_FILE = 'arena.yaml'
PARAMS_FILE = 'robot_params.yaml'


def robot_files(profile: str, out: Path, write: bool = True) -> tuple[str, Path | None]:
    """``(arena_file, params_file)`` of a run on the robot of ``profile`` into ``out``: the
    profile's own arena file and None when it is not scaled; else the scaled files (written
    with ``write``)."""
    robot = load_profile(profile)
    spec = robot.arena
    arena = load_arena(spec.path(), robot_radius=0.0)
    scale = spec.scale(arena.size)
    if scale == 1.0:
        return (str(spec.path()) if spec.file else ''), None
    arena_file, params_file = out / ARENA_FILE, out / PARAMS_FILE
    if write:
        files.write_text(arena_file, yaml.safe_dump(arena_data(scaled_arena(arena, scale)),
                                                     sort_keys=False))
        files.write_text(params_file, yaml.safe_dump(
            {'/**': {'ros__parameters': module_params(scale, robot.scan.range_max)}}))
    return str(arena_file), params_file


def module_params(scale: float, range_max: float) -> dict:
    """The module instances' keys that follow a robot whose arena is ``scale`` times the
    layout's and whose scan reads up to ``range_max`` [m] (module docstring)."""
    out: dict = {}
    for name, _, prm in load_clis_params().instances:
        loc = getattr(prm, 'localization', None)
        if loc is not None:
            out[name] = {'localization': {'cell_size': loc.cell_size * scale,
                                          'trans_noise_min': loc.trans_noise_min * scale}}
        d_max = getattr(prm, 'd_max', None)
        if d_max and range_max != d_max:
            r = range_max / d_max
            out[name] = {'d_max': range_max, 'phi_dist': prm.phi_dist * r * r}
    return out
