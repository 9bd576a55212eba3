"""Generated arena layouts (cr_sim.core.layout): the paper's situations, no overlap, the loader
accepts them, the same seed gives the same bytes; the situation check and the hidden share
agree with the simulator's camera."""

from __future__ import annotations

import copy
import itertools
import math

from clis_base.params import config_dir
from cr_sim.core.arena import load_arena, parse_arena
from cr_sim.core.layout import (
    LANDMARKS,
    SIZE,
    hidden_share,
    layout_for_seed,
    layout_yaml,
    passage,
    situation_problems,
)
from cr_sim.core.sim import Simulator, load_sim_params
import numpy as np
import pytest
import yaml

R = 0.11          # robot radius of config/robot.yaml
SEEDS = range(200)


@pytest.fixture(scope='module')
def exact():
    """The simulator's parameters without sensor noise: its camera sees exactly."""
    return load_sim_params(overrides={'sensors': {'ir_noise_sigma': 0.0,
                                                  'bearing_noise_deg': 0.0}})


def _gap(a, b) -> float:
    dx = max(b.lo[0] - a.hi[0], a.lo[0] - b.hi[0], 0.0)
    dy = max(b.lo[1] - a.hi[1], a.lo[1] - b.hi[1], 0.0)
    return math.hypot(dx, dy)


def test_generated_layouts_hold_their_invariants(tmp_path, exact):
    assert load_sim_params().robot.radius == R
    landmarks = set()
    for seed in SEEDS:
        path = tmp_path / f'gen{seed}.yaml'
        path.write_text(layout_yaml(layout_for_seed(seed, R)))
        arena = load_arena(path, R)                  # the loader accepts it (and checks it)
        where = f'seed {seed}'
        assert arena.size == SIZE and arena.centred_square, where
        assert (len(arena.short_obstacles), len(arena.tall_obstacles)) == (4, 2), where
        assert arena.start_names == tuple('ABCDE'), where
        # the paper's situations, geometrically ...
        assert situation_problems(arena, R) == [], where
        # ... and as the simulator's camera sees them from each start
        sim = Simulator(arena, exact, np.random.default_rng(0))
        for name in 'ABCDE':
            assert sim.reset(name).dest_visible == (name != 'E'), f'{where}, start {name}'
            assert abs(sim.reset(name).dest_bearing) < math.radians(0.2) or name == 'E', where
        # no overlap: obstacles a passage apart from each other, from the walls, from the goal
        gap = passage(R)
        for a, b in itertools.combinations(arena.obstacles, 2):
            assert _gap(a, b) >= gap - 1e-9, f'{where}: {a.name} {b.name}'
        half = arena.half
        d = arena.destination
        for b in arena.obstacles:
            assert min(b.lo[0] + half, b.lo[1] + half, half - b.hi[0], half - b.hi[1]) \
                >= gap - 1e-9, f'{where}: {b.name} and the wall'
            assert arena.gap(d.x, d.y, 0.0) >= gap - 1e-9, where
        # one landmark on each wall, in config/arena.yaml's order and colours
        on_wall = {'east': (half, None), 'north': (None, half), 'west': (-half, None),
                   'south': (None, -half)}
        for lm, (name, colour, wall) in zip(arena.landmarks, LANDMARKS, strict=True):
            x, y = on_wall[wall]
            assert lm.x == x if x is not None else lm.y == y, where
            assert (lm.name, lm.colour) == (name, colour), where
            landmarks.add((lm.name, lm.x, lm.y))
    assert len(landmarks) > 4 * 20                  # drawn along the walls, not fixed


def test_same_seed_same_bytes_other_seed_other_layout():
    texts = [layout_yaml(layout_for_seed(seed, R)) for seed in (5, 5, 6)]
    assert texts[0] == texts[1]
    assert texts[0] != texts[2]
    assert '--seed 5' in texts[0]
    assert yaml.safe_load(texts[0]) == layout_for_seed(5, R).data   # the text is the layout


def test_a_layout_seed_is_a_non_negative_integer():
    for bad in (-1, 1.5, '3', True):
        with pytest.raises(ValueError, match='seed'):
            layout_for_seed(bad, R)


def test_the_shipped_arenas_are_in_the_paper_situations():
    assert situation_problems(load_arena(config_dir() / 'arena.yaml', R), R) == []
    # arena_alt.yaml's C: its straight line clips the north-east corner of S1 (at x = -0.15
    # it is at y = 0.644, the corner at 0.65), so C is not in the situation its header names
    alt = situation_problems(load_arena(config_dir() / 'arena_alt.yaml', R), R)
    assert len(alt) == 1 and alt[0].startswith('C (clear): the straight line passes 0.0'), alt


def test_the_situation_check_sees_a_start_out_of_its_situation():
    base = yaml.safe_load((config_dir() / 'arena.yaml').read_text())
    cases = {
        'E': ({'x': 1.2, 'y': 0.7}, 'no tall obstacle hides'),            # in plain view
        'D': ({'x': -1.2, 'y': 0.5}, 'crosses no short obstacle'),        # passes S1 by
        'A': ({'x': 1.2, 'y': -0.7}, 'hidden'),                            # behind T1
        'B': ({'x': -1.2, 'y': 0.1}, 'passes 0.000 m from an obstacle'),   # through S1
        'C': ({'x': 1.0, 'y': -0.95}, 'passes 0.018 m from an obstacle'),  # grazes T1
    }
    for name, (pose, why) in cases.items():
        data = copy.deepcopy(base)
        data['starts'][name].update(pose)
        problems = situation_problems(parse_arena(data, R), R)
        assert len(problems) == 1 and problems[0].startswith(name), (name, problems)
        assert why in problems[0], (name, problems)
    # D: across S1 as it should be, but its line passes 0.10 m from a new tall obstacle
    data = copy.deepcopy(base)
    data['tall_obstacles'].append({'name': 'T3', 'center': [-0.9, 0.15], 'size': [0.1, 0.1]})
    assert situation_problems(parse_arena(data, R), R) == [
        'D (short_across): the straight line passes 0.100 m from a tall obstacle (< the robot '
        'radius 0.11 m)']
    data = copy.deepcopy(base)
    del data['starts']['C']
    assert situation_problems(parse_arena(data, R), R) == ['C (clear): no such start']


def test_a_far_destination_is_hidden_beyond_the_camera_range():
    arena = load_arena(config_dir() / 'arena.yaml', R)
    assert situation_problems(arena, R, camera_range=1.0)[0].startswith('A (clear): the '
                                                                         'destination is hidden')
    assert hidden_share(arena, R, camera_range=0.5) > 0.8 > hidden_share(arena, R)


def test_hidden_share_is_what_the_camera_sees_from_each_free_cell(exact):
    res = 0.1
    for arena in (load_arena(config_dir() / 'arena.yaml', R),
                  parse_arena(layout_for_seed(11, R).data, R)):
        sim = Simulator(arena, exact, np.random.default_rng(0))
        hidden = free = 0
        for x in np.arange(-SIZE / 2 + res / 2, SIZE / 2, res):
            for y in np.arange(-SIZE / 2 + res / 2, SIZE / 2, res):
                try:
                    obs = sim.reset(start=(x, y, 0.0))
                except ValueError:
                    continue                            # the robot does not fit here
                free += 1
                hidden += not obs.dest_visible
        assert 0 < hidden < free
        assert hidden_share(arena, R, resolution=res) == pytest.approx(hidden / free, abs=1e-12)
    empty = yaml.safe_load((config_dir() / 'arena.yaml').read_text())
    empty['tall_obstacles'] = []
    assert hidden_share(parse_arena(empty, R), R) == 0.0
