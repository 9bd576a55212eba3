"""Smoke runs of CLIS through the standard path (``clis run --robot ros --profile P``: the blob
detector, the robot adapter and the CLIS graph in ``/clis``): on a robot nobody here wrote,
Clearpath's Husky in its PyBullet world (``husky_world world``, publishing only ``/clock``,
``odom``, ``scan``, ``image_raw``, ``camera_info``), and on our own simulator as a plain world
(started by ``clis run``). Both worlds wait for the graph (lockstep: the Husky world's
``lockstep`` parameter and ``clis run --lockstep``; our simulator always), so the view module
decides from the first frame of every episode on any host. Judged by what the learner wrote
(episodes numbered from 1, each within the profile's time limit of sim time, each learned and
driven by the view module) and by the adapter's log, never by wall-clock rates; and, on the
Husky, by a second run of the same seed: in lockstep the standard path repeats bit for bit."""

from __future__ import annotations

import csv
from pathlib import Path
import subprocess
import sys

from clis_base.params import config_dir
import pytest
from ros_util import start_node, stop
import yaml

pytestmark = pytest.mark.ros

EPISODES = 3
TIME_LIMIT = 6.0                      # [s of sim time] the episodes of a smoke run


def short_profile(tmp_path: Path, name: str) -> Path:
    """Profile ``name`` with short episodes (a profile may be any file)."""
    data = yaml.safe_load((config_dir() / 'robots' / f'{name}.yaml').read_text(encoding='utf-8'))
    data['episode']['time_limit'] = TIME_LIMIT
    data['episode']['wander_time'] = 1.0
    path = tmp_path / f'{name}_short.yaml'
    path.write_text(yaml.safe_dump(data), encoding='utf-8')
    return path


def clis_run(tmp_path: Path, profile: Path, *extra: str, out: str = 'run'
             ) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, '-m', 'clis_app.cli', 'run', '--robot', 'ros', '--profile',
         str(profile), '--condition', 'view', '--episodes', str(EPISODES), '--out',
         str(tmp_path / out), '--quiet', '--startup-timeout', '120', *extra],
        capture_output=True, text=True, timeout=420)


def husky_run(tmp_path: Path, profile: Path, out: str) -> None:
    """The Husky world in lockstep, its sensors at 4 Hz (View's 0.5 s decisions fall on every
    other frame: bench_robots' rate), and ``clis run --lockstep`` on it into ``tmp_path/out``."""
    world = start_node('husky_world.world_node', '-p', 'real_time_factor:=0.0',
                       '-p', 'lockstep:=true', *(x for k in ('clock', 'odom', 'scan', 'image')
                                                  for x in ('-p', f'{k}_rate:=4.0')))
    try:
        proc = clis_run(tmp_path, profile, '--lockstep', out=out)
    finally:
        world_out = stop(world)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert 'Traceback' not in world_out, world_out


def test_clis_learns_episodes_on_the_husky_world_and_repeats_bit_for_bit(tmp_path):
    profile = short_profile(tmp_path, 'husky')
    husky_run(tmp_path, profile, 'run')
    check_run(tmp_path)
    # the same seed again, a new world: every episode's row and every learned weight repeat
    husky_run(tmp_path, profile, 'again')
    first, again = tmp_path / 'run', tmp_path / 'again'
    assert ((again / 'episodes.csv').read_text(encoding='utf-8')
            == (first / 'episodes.csv').read_text(encoding='utf-8'))
    assert (again / 'checkpoint.npz').read_bytes() == (first / 'checkpoint.npz').read_bytes()


def test_clis_learns_episodes_on_our_simulator_through_the_standard_path(tmp_path):
    """A profile of our simulator (``simulator: cr_sim``, here a copy of cr's) makes ``clis
    run`` start the simulator as a plain world, in lockstep."""
    proc = clis_run(tmp_path, short_profile(tmp_path, 'cr'))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    check_run(tmp_path)
    assert (tmp_path / 'run' / 'logs' / 'sim.log').is_file(), 'clis run started the simulator'


def check_run(tmp_path: Path) -> None:
    with open(tmp_path / 'run' / 'episodes.csv', newline='') as fh:
        rows = list(csv.DictReader(fh))
    assert [int(r['episode']) for r in rows] == list(range(1, EPISODES + 1)), rows
    for r in rows:
        assert 0.0 < float(r['duration']) <= TIME_LIMIT + 0.1, r
        # the view module drove from the first frame on (the world waits for it)
        assert r['behaviour'] == 'view' and float(r['share_view']) == 1.0, r
    assert (tmp_path / 'run' / 'checkpoint.npz').is_file()
    # the robot was driven through the standard path: the adapter chose the world's type
    logs = '\n'.join(p.read_text(errors='replace') for p in (tmp_path / 'run' / 'logs').glob('*'))
    assert 'TwistStamped' in logs, logs[-2000:]
