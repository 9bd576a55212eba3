"""``clis run --resume CKPT --out SAME`` continues the run (real processes).

A run of 2 short episodes, then ``--resume`` from its checkpoint into the same ``--out`` for 2
more: the episodes are numbered 1-4 in one table (the rows written after the checkpoint are
dropped and run again), the checkpoint is at episode 4, and the resumed episodes have draws of
their own: they do not replay episodes 1 and 2 (the innate module does not learn its actions,
so a replay of the simulator's draws gave the same durations, collisions and returns).
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
import subprocess
import sys

from clis_learner.core.episodes import keep_rows_until
import numpy as np
import pytest

#: short episodes (the time limit) and a short wander between them
PARAMS = '/**:\n  ros__parameters:\n    episode: {time_limit: 4.0, wander_time: 1.0}\n'


def clis_run(out: Path, params: Path, *args: str) -> None:
    res = subprocess.run([sys.executable, '-m', 'clis_app.cli', 'run', '--condition',
                          'innate', '--episodes', '2', '--params', str(params), '--out', str(out),
                          '--quiet', *args], capture_output=True, text=True, timeout=600)
    logs = '\n'.join(f'--- {p.name}\n{p.read_text()[-2000:]}'
                     for p in sorted((out / 'logs').glob('*.log'))) if out.is_dir() else ''
    assert res.returncode == 0, f'{res.stdout}{res.stderr}\n{logs}'


def rows(out: Path) -> list[dict[str, str]]:
    with open(out / 'episodes.csv', newline='') as fh:
        return list(csv.DictReader(fh))


def meta(path: Path) -> dict:
    with np.load(path, allow_pickle=False) as npz:
        return json.loads(str(npz['__meta__']))['extra']


def test_resume_into_the_same_out_numbers_on_and_draws_anew(tmp_path):
    params = tmp_path / 'short.yaml'
    params.write_text(PARAMS)
    out = tmp_path / 'run'
    clis_run(out, params)
    first = rows(out)
    assert [r['episode'] for r in first] == ['1', '2']
    assert meta(out / 'checkpoint.npz')['episode'] == 2
    # where it goes on: the robot, the clock (7 hex floats) and the random streams (base64)
    assert len(meta(out / 'checkpoint.npz')['sim_state'].split()) == 8
    stale = dict(first[-1], episode='3', label='stale')   # written after the checkpoint
    with open(out / 'episodes.csv', 'a', newline='') as fh:
        csv.DictWriter(fh, fieldnames=list(stale)).writerow(stale)

    clis_run(out, params, '--resume', str(out / 'checkpoint.npz'))
    text = (out / 'episodes.csv').read_text().splitlines()
    assert sum(line.startswith('label,') for line in text) == 1, text
    after = rows(out)
    assert [r['episode'] for r in after] == ['1', '2', '3', '4'], after
    assert after[:2] == first
    assert all(r['label'] == 'innate' for r in after)
    assert meta(out / 'checkpoint.npz')['episode'] == 4

    def outcome(r: dict) -> tuple:
        return r['duration'], r['collisions'], r['ret']
    assert [outcome(r) for r in after[2:]] != [outcome(r) for r in first], after


@pytest.mark.parametrize('keep, expect', [(2, ['1', '2']), (5, ['1', '2', '3']), (0, [])])
def test_keep_rows_until(tmp_path, keep, expect):
    path = tmp_path / 'episodes.csv'
    path.write_text('label,episode,ret\na,1,0.5\na,2,1.0\na,3,-0.1\n')
    dropped = keep_rows_until(path, keep)
    with open(path, newline='') as fh:
        assert [r['episode'] for r in csv.DictReader(fh)] == expect
    assert dropped == 3 - len(expect)


def test_a_simulator_carried_into_a_new_one_goes_on_to_the_bit():
    """What ``clis run --resume`` does with the simulator: each episode reseeded from
    (seed, episode), and a new simulator that takes the pose an episode ended with runs the
    next episodes exactly as the one that went on (wander, motion, noise)."""
    from cr_sim.core.arena import load_arena
    from cr_sim.core.sim import Simulator, load_sim_params
    arena, params = load_arena(None), load_sim_params()

    def episode(sim: Simulator, k: int) -> tuple[np.ndarray, tuple]:
        sim.reseed(np.random.default_rng([5, 0, k]))
        sim.reset('wander')
        wheels, trace = np.random.default_rng([9, k]), []
        while not sim.done and len(trace) < 60:
            res = sim.step(wheels.uniform(-0.3, 0.6, 2))
            trace.append((res.reward, *sim.pose, *sim.observe().ir))
        return np.array(trace), sim.carried()

    sim = Simulator(arena, params, np.random.default_rng([5, 0]))
    runs, carried = zip(*[episode(sim, k) for k in range(1, 5)])
    for cut in (1, 2, 3):
        other = Simulator(arena, params, np.random.default_rng([5, 0]))
        other.carry(carried[cut - 1])
        for k in range(cut + 1, 5):
            trace, _ = episode(other, k)
            assert trace.tobytes() == runs[k - 1].tobytes(), (cut, k)


def test_a_checkpoint_is_the_same_bytes_whenever_it_is_written(tmp_path):
    import zipfile

    from clis_learner.core.checkpoint import ZIP_TIME, load_checkpoint, save_checkpoint
    from clis_learner.core.config import load_clis_params
    from clis_modules.core.modules import arena_map, make_modules
    from cr_sim.core.arena import load_arena
    modules = make_modules(load_clis_params(), 'view', *arena_map(load_arena(None)))
    path = save_checkpoint(tmp_path / 'a.npz', modules, 'h', {'episode': 3})
    with zipfile.ZipFile(path) as zf:
        assert {i.date_time for i in zf.infolist()} == {ZIP_TIME}
    assert load_checkpoint(path, modules, 'h')['extra'] == {'episode': 3}
    again = save_checkpoint(tmp_path / 'b.npz', modules, 'h', {'episode': 3})
    assert again.read_bytes() == path.read_bytes()
