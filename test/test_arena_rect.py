"""A lab's arena that is not the paper's square: config/arena_lab.yaml, 3.6 m x 2.4 m with its
origin at the floor's south-west corner. The simulator, the place module's grid, the Fig. 4
map and the graph follow it; the paper's centred square is unchanged."""

from __future__ import annotations

import csv
import json
import math

from clis_app.cli import main as clis
from clis_learner.core.config import load_clis_params
from clis_modules.core.localization import MarkovLocalizer
from clis_modules.core.modules import arena_map
from cr_sim.core.arena import ArenaError, load_arena, parse_arena
from cr_sim.core.sim import Simulator, load_sim_params
from cr_sim.core.wander import WanderPolicy
import numpy as np
import pytest
import yaml

PARAMS = load_sim_params()
R = PARAMS.robot.radius


@pytest.fixture(scope='module')
def lab(repo):
    return load_arena(repo / 'config' / 'arena_lab.yaml')


def test_the_floor_is_a_rectangle_in_the_labs_frame(lab, repo):
    assert lab.bounds == (0.0, 0.0, 3.6, 2.4)
    assert (lab.width, lab.height, lab.size) == pytest.approx((3.6, 2.4, 3.6))
    assert not lab.centred_square and lab.floor() == lab.bounds
    with pytest.raises(ValueError, match='not a square centred'):
        _ = lab.half
    square = load_arena()
    assert square.centred_square and square.bounds == (-1.5, -1.5, 1.5, 1.5)
    assert square.floor() == 1.5 == square.half
    walls = lab.wall_boxes(0.05)
    assert walls[1] == pytest.approx((3.6, -0.05, 3.65, 2.45))      # east
    assert lab.gap(3.6 - R - 0.01, 1.2, R) == pytest.approx(0.01)
    assert lab.gap(1.0, 2.4 - R - 0.02, R) == pytest.approx(0.02)


def test_bad_floors_are_named(repo):
    data = yaml.safe_load((repo / 'config' / 'arena_lab.yaml').read_text())
    both = dict(data, size=3.0)
    with pytest.raises(ArenaError, match='not both'):
        parse_arena(both, R)
    bad = dict(data, floor={'width': 3.6, 'height': -1.0, 'origin': [0, 0]})
    with pytest.raises(ArenaError, match='floor.height'):
        parse_arena(bad, R)
    shifted = dict(data, floor={'width': 3.6, 'height': 2.4, 'origin': [0.5, 0.0]})
    with pytest.raises(ArenaError, match="landmark 'L3'"):
        parse_arena(shifted, R)                      # L3 at x = 0 is now outside the wall
    out = dict(data, landmarks=[{'name': 'L1', 'colour': 'red', 'x': 3.7, 'y': 1.0}])
    with pytest.raises(ArenaError, match=r'x in \[0, 3.6\], y in \[0, 2.4\]'):
        parse_arena(out, R)


def test_simulator_follows_the_floor(lab):
    sim = Simulator(lab, PARAMS, np.random.default_rng(0))
    xy = []
    for _ in range(300):
        sim.reset('random')
        xy.append(sim.pose[:2])
    xy = np.array(xy)
    assert xy[:, 0].min() >= R and xy[:, 0].max() <= 3.6 - R
    assert xy[:, 1].min() >= R and xy[:, 1].max() <= 2.4 - R
    assert xy[:, 0].max() > 2.8 and xy[:, 1].min() < 0.6, 'the whole floor is used'
    # drive east into the east wall: the robot stops at contact, x = 3.6 - r
    sim.reset(start=(3.0, 2.1, 0.0))
    hits = [sim.step((0.5, 0.5)).collision for _ in range(40)]
    assert sum(hits) == 1 and sim.pose[0] == pytest.approx(3.6 - R, abs=1e-4)
    # the IR beam straight ahead reads the wall's distance; the camera the paper's situations
    sim.reset(start=(3.0, 2.1, 0.0))
    assert sim.observe().ir[3] == pytest.approx(3.6 - 3.0 - R, abs=0.02)
    for name in 'ABCD':
        sim.reset(start=name)
        assert abs(sim.observe().dest_bearing) < math.radians(5), name
    sim.reset(start='E')
    assert math.isnan(sim.observe().dest_bearing), 'T1 hides the destination from E'


def test_the_place_module_localizes_within_one_cell(lab):
    """Wander with the full sensor model (noise on), the place module's localizer on the
    executed wheels and the landmark bearings every 1.2 s: median error below one cell."""
    landmarks, floor, boxes = arena_map(lab)
    params = load_clis_params().place.localization
    loc = MarkovLocalizer(params, landmarks, floor, boxes)
    assert loc.origin == (0.0, 0.0) and loc.shape[1:] == (24, 16)
    assert loc.xs[-1] == pytest.approx(3.6 - 0.075) and loc.ys[-1] == pytest.approx(2.4 - 0.075)
    sim = Simulator(lab, load_sim_params(overrides={'episode.time_limit': 3600.0}),
                    np.random.default_rng(4))
    sim.reset('C')
    wheels, errors = [], []
    wander = WanderPolicy(PARAMS.wander, np.radians(PARAMS.sensors.ir_angles_deg),
                          np.random.default_rng(5))
    for k in range(1, 24 * 60 + 1):                 # 60 decisions of the place module
        res = sim.step(wander.act(sim.observe()))
        wheels.append(res.obs.wheels)
        obs = res.obs
        if res.done:                                 # over the goal: wander on from there
            sim.reset(start=sim.pose)
        if k % 24 == 0:
            loc.predict_wheels(np.array(wheels), PARAMS.episode.dt, PARAMS.robot.wheel_base)
            wheels.clear()
            loc.update(obs.landmark_bearings)
            x, y, _ = loc.map_pose()
            errors.append(math.hypot(x - sim.pose[0], y - sim.pose[1]))
    median = float(np.median(errors[5:]))
    print(f'rectangular arena: localization error median {100 * median:.1f} cm '
          f'(cell {100 * loc.cell:.0f} cm)')
    assert median <= loc.cell


def test_headless_experiment_runs_in_it_with_the_fig4_map(lab, repo, tmp_path):
    out = tmp_path / 'exp'
    assert clis(['experiment', '--conditions', 'async', '--episodes', '2', '--block', '2',
                 '--seeds', '1', '--eval-episodes', '1', '--workers', '1', '--out', str(out),
                 '--quiet', '--arena', str(repo / 'config' / 'arena_lab.yaml')]) == 0
    run = json.loads(next((out / 'runs').glob('*.json')).read_text())
    assert run['arena']['bounds'] == [0.0, 0.0, 3.6, 2.4]
    pm = run['place_map']
    assert min(pm['x']) > 0 and max(pm['x']) < 3.6 and max(pm['y']) < 2.4
    assert np.shape(pm['p']) == (len(pm['y']), len(pm['x'])) == (24, 36)
    assert (out / 'fig4.png').stat().st_size > 1000
    import matplotlib
    matplotlib.use('Agg')
    from clis_app.experiments import figures
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots()
    figures.draw_arena(ax, run['arena'])
    assert ax.get_xlim() == (0.0, 3.6) and ax.get_ylim() == (0.0, 2.4), 'the figure is the floor'
    plt.close(fig)
    with open(out / 'episodes.csv') as fh:
        assert len(list(csv.DictReader(fh))) == 2


@pytest.mark.ros
def test_the_graph_runs_in_it(repo, tmp_path):
    from test_graph import clis_run, finish
    out = tmp_path / 'run'
    code, text = finish(clis_run(out, '--condition', 'place', '--episodes', '2', '--arena',
                                 str(repo / 'config' / 'arena_lab.yaml')), 300)
    assert code == 0, text
    with open(out / 'episodes.csv', newline='') as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) >= 2 and all(r['learned'] == '1' for r in rows[:2])
    assert 'Traceback' not in (out / 'logs' / 'place.log').read_text()
