"""Tests of the pure simulator core (cr_sim.core): geometry, kinematics, contacts, sensors,
rewards, episode end, config validation, the arena layout and reproducibility."""

from __future__ import annotations

import copy
import math
from pathlib import Path

from clis_base.params import ConfigError, config_dir, load_yaml, replace
from cr_sim.core import sim as sim_module
from cr_sim.core.arena import ArenaError, load_arena, parse_arena
from cr_sim.core.geometry import (
    raycast,
    segment_box_distance,
    segments_blocked,
    slab,
    wall_boxes,
    wrap_angle,
    wrap_angles,
)
from cr_sim.core.observation import Observation
from cr_sim.core.robot import (
    clamp_wheels,
    integrate_arc,
    load_robot_params,
    twist_to_wheels,
    wheels_to_twist,
)
from cr_sim.core.sim import Simulator, load_sim_params
import numpy as np
import pytest
import yaml

# results pinned bit for bit: tools/cpu_check.py runs these under each CPU kernel set
pytestmark = pytest.mark.bits

R = 0.11          # robot radius of config/robot.yaml (checked below)
VMAX = 1.3
DT = 0.05


# ------------------------------------------------------------------------------ fixtures

@pytest.fixture(scope='module')
def params():
    """Default parameters."""
    return load_sim_params()


@pytest.fixture(scope='module')
def exact():
    """Default parameters without sensor noise (hand-computed cases)."""
    return load_sim_params(overrides={'sensors': {'ir_noise_sigma': 0.0,
                                                  'bearing_noise_deg': 0.0}})


@pytest.fixture(scope='module')
def arena(params):
    """The default arena."""
    return load_arena(robot_radius=params.robot.radius)


def arena_dict(**top) -> dict:
    """A bare arena: empty floor, destination at the origin, one landmark on the east wall."""
    data = {
        'size': 3.0,
        'destination': {'x': 0.0, 'y': 0.0, 'goal_radius': 0.15},
        'short_obstacles': [],
        'tall_obstacles': [],
        'landmarks': [{'name': 'L1', 'colour': 'red', 'x': 1.5, 'y': 0.0},
                      {'name': 'L2', 'colour': 'blue', 'x': 0.0, 'y': 1.5}],
        'starts': {'A': {'x': -1.0, 'y': 0.0, 'heading_deg': 0.0}},
    }
    data.update(top)
    return data


def make_sim(p, data=None, seed=0) -> Simulator:
    a = parse_arena(data if data is not None else arena_dict(), p.robot.radius)
    return Simulator(a, p, np.random.default_rng(seed))


def default_arena_data() -> dict:
    return load_yaml(config_dir() / 'arena.yaml')


def write_yaml(path: Path, data: dict) -> Path:
    path.write_text(yaml.safe_dump(data), encoding='utf-8')
    return path


# ------------------------------------------------------------------------ config values

def test_config_values_used_by_these_tests(params):
    assert params.robot.radius == R
    assert params.robot.v_wheel_max == VMAX
    assert params.episode.dt == DT
    assert params.episode.time_limit == 60.0
    assert params.episode.reward_goal == 1.0
    assert params.episode.reward_collision == -0.1
    assert len(params.sensors.ir_angles_deg) == 7


def test_robot_yaml_out_of_range_names_the_file_and_the_key(tmp_path):
    data = load_yaml(config_dir() / 'robot.yaml')
    data['/**']['ros__parameters']['robot']['radius'] = 5.0
    path = write_yaml(tmp_path / 'robot.yaml', data)
    with pytest.raises(ConfigError, match=r'robot\.yaml: robot\.radius.*out of range'):
        load_robot_params(path)
    with pytest.raises(ConfigError, match=r'robot\.yaml: robot\.radius.*out of range'):
        load_sim_params(robot_path=path)


def test_the_body_is_described_once_in_robot_yaml(tmp_path):
    """The simulator's parameters take the body from robot.yaml; a sim file with a robot
    section of its own is refused, naming robot.yaml."""
    body = load_robot_params()
    assert load_sim_params().robot == body
    data = load_yaml(config_dir() / 'robot.yaml')
    data['/**']['ros__parameters']['robot']['wheel_base'] = 0.2
    assert load_sim_params(robot_path=write_yaml(tmp_path / 'r.yaml', data)).robot == \
        replace(body, wheel_base=0.2)
    data = load_yaml(config_dir() / 'sim.yaml')
    assert 'robot' not in data['sim']['ros__parameters']
    data['sim']['ros__parameters']['robot'] = {'radius': 0.11, 'wheel_base': 0.16,
                                               'v_wheel_max': 1.3}
    with pytest.raises(ConfigError, match=r'section robot.*robot\.yaml'):
        load_sim_params(write_yaml(tmp_path / 'sim.yaml', data))


def test_sim_yaml_missing_and_unknown_keys(tmp_path):
    data = load_yaml(config_dir() / 'sim.yaml')
    del data['sim']['ros__parameters']['episode']['dt']
    with pytest.raises(ConfigError, match=r'missing key sim\.episode\.dt'):
        load_sim_params(write_yaml(tmp_path / 'a.yaml', data))
    data = load_yaml(config_dir() / 'sim.yaml')
    data['sim']['ros__parameters']['sensors']['ir_rnage'] = 0.5
    with pytest.raises(ConfigError, match=r'unknown key sim\.sensors\.ir_rnage'):
        load_sim_params(write_yaml(tmp_path / 'b.yaml', data))
    # the ROS node's own section is left to the node
    data = load_yaml(config_dir() / 'sim.yaml')
    data['sim']['ros__parameters']['node'] = {'speed_factor': 10.0}
    assert load_sim_params(write_yaml(tmp_path / 'c.yaml', data)).robot.radius == R


def test_overrides_dotted_and_nested():
    p = load_sim_params(overrides={'robot.radius': 0.1, 'episode': {'dt': 0.1}})
    assert p.robot.radius == 0.1 and p.episode.dt == 0.1
    with pytest.raises(ConfigError, match=r'episode\.dt.*out of range'):
        load_sim_params(overrides={'episode.dt': -1.0})
    with pytest.raises(ConfigError, match='no_such_key'):
        load_sim_params(overrides={'robot.no_such_key': 1.0})
    with pytest.raises(ConfigError, match=r'v_wheel_max.*out of range'):
        load_sim_params(overrides={'robot.v_wheel_max': 2.0})   # the CR cannot exceed 1.3


# ---------------------------------------------------------------------------- geometry

def test_wrap_angle():
    for a, want in [(0.0, 0.0), (math.pi, math.pi), (-math.pi, math.pi), (3 * math.pi, math.pi),
                    (-0.5, -0.5), (2 * math.pi + 0.25, 0.25), (-2 * math.pi - 0.25, -0.25),
                    (math.pi + 0.1, -math.pi + 0.1), (-math.pi - 0.1, math.pi - 0.1)]:
        assert wrap_angle(a) == pytest.approx(want, abs=1e-12)
        assert wrap_angles(np.array([a]))[0] == pytest.approx(want, abs=1e-12)
    a = np.random.default_rng(0).uniform(-50, 50, 10_000)
    w = wrap_angles(a.copy())
    assert np.all((w > -math.pi) & (w <= math.pi))
    assert np.allclose(np.cos(w), np.cos(a)) and np.allclose(np.sin(w), np.sin(a))
    assert np.isnan(wrap_angles(np.array([np.nan]))[0])


def test_raycast_hand_cases():
    box = np.array([[[0.4, -0.2], [0.6, 0.2]]])                   # x in [0.4, 0.6]
    d = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [math.cos(0.3), math.sin(0.3)]])
    t = raycast(0.0, 0.0, d, box)
    assert t[0] == pytest.approx(0.4)                             # straight at the face
    assert t[1] == np.inf and t[2] == np.inf                      # behind / beside
    assert t[3] == pytest.approx(0.4 / math.cos(0.3))             # 0.4*tan(0.3)=0.12 < 0.2
    walls = wall_boxes(1.5)
    t = raycast(1.0, 0.5, np.array([[1.0, 0.0], [0.0, -1.0], [-1.0, 0.0]]), walls)
    assert t == pytest.approx([0.5, 2.0, 2.5])
    # exact zero direction components (heading 0 along a box edge) never give NaN
    tn, tf = slab(0.0, 0.2, np.array([[1.0, 0.0]]), box)
    assert np.isfinite(tn).all() and np.isfinite(tf).all()


def test_segments_and_segment_box_distance():
    box = np.array([[[-0.1, -0.1], [0.1, 0.1]]])
    blocked = segments_blocked(-1.0, 0.0, np.array([[1.0, 0.0], [1.0, 1.0], [-0.5, 0.0]]), box)
    assert blocked.tolist() == [True, False, False]
    assert segment_box_distance((-1, 0.3), (1, 0.3), (-0.1, -0.1), (0.1, 0.1)) \
        == pytest.approx(0.2)
    assert segment_box_distance((-1, 0.0), (1, 0.0), (-0.1, -0.1), (0.1, 0.1)) == 0.0
    assert segment_box_distance((0.3, 0.3), (1, 1), (-0.1, -0.1), (0.1, 0.1)) \
        == pytest.approx(math.hypot(0.2, 0.2))


# -------------------------------------------------------------------------- kinematics

def test_twist_wheels_inverse_and_arc():
    v, w = wheels_to_twist(0.2, 0.6, 0.16)
    assert (v, w) == pytest.approx((0.4, 2.5))
    assert twist_to_wheels(v, w, 0.16) == pytest.approx((0.2, 0.6))
    assert integrate_arc(0.0, 0.0, 0.0, 1.0, 0.0, 2.0) == pytest.approx((2.0, 0.0, 0.0))
    assert integrate_arc(1.0, 2.0, 0.3, 0.0, 1.0, 0.5) == pytest.approx((1.0, 2.0, 0.8))
    rad = 2.0 / math.pi                                            # quarter circle, radius v/w
    assert integrate_arc(0.0, 0.0, 0.0, 1.0, math.pi / 2, 1.0) == \
        pytest.approx((rad, rad, math.pi / 2))
    # tiny yaw rate: continuous with the straight line
    assert integrate_arc(0.0, 0.0, 0.0, 1.0, 1e-12, 1.0) == pytest.approx((1.0, 0.0, 0.0))


def test_clamp_wheels():
    assert clamp_wheels([0.5, -0.5], 1.3).tolist() == [0.5, -0.5]
    assert clamp_wheels([2.0, -9.0], 1.3).tolist() == [1.3, -1.3]
    assert clamp_wheels([np.nan, 1.0], 1.3).tolist() == [0.0, 1.0]
    assert clamp_wheels([np.inf, -np.inf], 1.3).tolist() == [0.0, 0.0]
    assert clamp_wheels(np.array([1e300, -1e300], dtype=np.float64), 1.3).tolist() == [1.3, -1.3]
    for bad in ([1.0], [1.0, 2.0, 3.0], 'ab', None):
        with pytest.raises(ValueError):
            clamp_wheels(bad, 1.3)


def test_bad_commands_never_move_too_far_nor_reach_the_pose(params):
    sim = make_sim(params)
    sim.reset(start=(0.0, -0.8, 0.3))
    rng = np.random.default_rng(3)
    pool = [np.nan, np.inf, -np.inf, 1e9, -1e9, 5.0, -5.0, 0.7, -0.2]
    for _ in range(300):
        before = sim.pose
        res = sim.step([pool[rng.integers(len(pool))], pool[rng.integers(len(pool))]])
        after = sim.pose
        assert np.isfinite(after).all() and np.isfinite(sim.wheels).all()
        assert np.all(np.abs(sim.wheels) <= VMAX)
        assert math.hypot(*(after[:2] - before[:2])) <= VMAX * DT + 1e-12
        assert np.isfinite(res.obs.ir).all()
        if res.done:
            sim.reset(start=(0.0, -0.8, 0.3))


# ----------------------------------------------------------------------------- sensors

def test_ir_hand_cases(exact, arena):
    sim = Simulator(arena, exact, np.random.default_rng(0))
    # at D facing east: short obstacle S1 has its west face at x = -0.65
    obs = sim.reset('D')
    ang = np.radians(exact.sensors.ir_angles_deg)
    front = int(np.argmin(np.abs(ang)))
    assert obs.ir[front] == pytest.approx((-0.65 - -1.2) - R)
    assert obs.d_o == pytest.approx(0.44)
    # bare floor, 1.0 m from the east wall, facing it: beam at angle a reads 0.5/cos(a) - r
    sim = make_sim(exact)
    obs = sim.reset(start=(1.0, 0.0, 0.0))
    for k, a in enumerate(ang):
        want = 0.5 / math.cos(a) - R if abs(a) < math.pi / 2 - 1e-9 else np.inf
        assert obs.ir[k] == pytest.approx(min(want, exact.sensors.ir_range))
    # pressed against the wall: the front beam reads ~0
    for _ in range(20):
        sim.step((1.0, 1.0))
    assert sim.observe().ir[front] == pytest.approx(0.0, abs=1e-6)
    # robot facing north, box face 0.4 m to the north: gap 0.4 - r; beam at 30 deg reads
    # 0.4/cos(30 deg) - r (hits at x = 0.4 tan 30 = 0.23 < 0.5, the box half width)
    data = arena_dict(short_obstacles=[{'name': 'B', 'center': [0.0, 0.5], 'size': [1.0, 0.2]}],
                      destination={'x': -1.0, 'y': -1.0, 'goal_radius': 0.15})
    sim = make_sim(exact, data)
    obs = sim.reset(start=(0.0, 0.0, math.pi / 2))
    assert obs.ir[front] == pytest.approx(0.4 - R)
    k30 = int(np.argmin(np.abs(ang - math.radians(30))))
    assert obs.ir[k30] == pytest.approx(0.4 / math.cos(math.radians(30)) - R)


def test_ir_noise_stays_in_range(params, arena):
    sim = Simulator(arena, params, np.random.default_rng(1))
    sim.reset('D')
    readings = np.array([sim.step((0.0, 0.0)).obs.ir for _ in range(200)])
    assert readings.min() >= 0.0 and readings.max() <= params.sensors.ir_range
    assert readings[:, 3].std() > 0.0   # noise is on


def test_occlusion_hand_cases(exact):
    tall = {'name': 'T', 'center': [-0.5, 0.0], 'size': [0.2, 0.2]}
    short = {'name': 'S', 'center': [-0.5, 0.0], 'size': [0.2, 0.2]}
    obs = make_sim(exact, arena_dict(tall_obstacles=[tall])).reset('A')
    assert math.isnan(obs.dest_bearing) and not obs.dest_visible
    assert obs.landmarks_visible.tolist() == [False, True]   # L1 behind T too, L2 not
    obs = make_sim(exact, arena_dict(short_obstacles=[short])).reset('A')
    assert obs.dest_bearing == pytest.approx(0.0, abs=1e-12)
    assert obs.landmarks_visible.all()
    # the segment just passes beside the tall box: seen
    obs = make_sim(exact, arena_dict(tall_obstacles=[tall])).reset(start=(-1.0, 0.3, 0.0))
    assert obs.dest_visible


def test_camera_range():
    p = load_sim_params(overrides={'sensors.camera_range': 0.9, 'sensors.bearing_noise_deg': 0.0})
    obs = make_sim(p).reset('A')           # destination 1.0 m away
    assert math.isnan(obs.dest_bearing)
    obs = make_sim(p).reset(start=(-0.8, 0.0, 0.0))
    assert obs.dest_bearing == pytest.approx(0.0)


def test_the_destination_has_a_range_of_its_own():
    """``destination_range`` hides the destination beyond it and leaves the landmarks to
    ``camera_range``; 0 (the default) is ``camera_range`` for every blob."""
    p = load_sim_params(overrides={'sensors.destination_range': 0.9,
                                   'sensors.bearing_noise_deg': 0.0})
    obs = make_sim(p).reset('A')           # destination 1.0 m away, landmarks up to 3.0 m
    assert math.isnan(obs.dest_bearing) and obs.landmarks_visible.all()
    obs = make_sim(p).reset(start=(-0.8, 0.0, 0.0))
    assert obs.dest_bearing == pytest.approx(0.0)
    both = load_sim_params(overrides={'sensors.camera_range': 0.9,
                                      'sensors.bearing_noise_deg': 0.0})
    assert not make_sim(both).reset('A').landmarks_visible.any()
    assert load_sim_params().sensors.destination_range == 0.0


def test_bearings_and_wrap(exact):
    sim = make_sim(exact)
    # robot south of the destination: bearing = pi/2 - heading, wrapped
    for heading, want in [(0.0, math.pi / 2), (math.pi / 2, 0.0), (-math.pi / 2, math.pi),
                          (math.pi / 2 + 0.1, -0.1), (-math.pi / 2 - 0.3, -math.pi + 0.3),
                          (math.pi, -math.pi / 2)]:
        obs = sim.reset(start=(0.0, -1.0, heading))
        assert obs.dest_bearing == pytest.approx(want, abs=1e-12)
        assert -math.pi < obs.dest_bearing <= math.pi
    # landmarks in file order: L1 east (1.5, 0), L2 north (0, 1.5), seen from (0, -1) facing east
    obs = sim.reset(start=(0.0, -1.0, 0.0))
    assert obs.landmark_bearings == pytest.approx([math.atan2(1.0, 1.5), math.pi / 2])
    assert isinstance(obs, Observation)
    with pytest.raises((AttributeError, TypeError)):
        obs.t = 3.0
    with pytest.raises(ValueError):
        obs.ir[0] = 1.0


# -------------------------------------------------------------------- contact, reward

def _drive(sim, u, n):
    out = []
    for _ in range(n):
        res = sim.step(u)
        assert sim.gap >= -1e-9, 'penetration'
        out.append(res)
    return out


def test_wall_contact_once_no_penetration_and_turn_away(params):
    sim = make_sim(params)
    sim.reset(start=(1.0, 0.0, 0.0))
    res = _drive(sim, (VMAX, VMAX), 40)
    assert [r.reward for r in res].count(-0.1) == 1
    assert sum(r.collision for r in res) == 1
    assert all(r.reward in (0.0, -0.1) for r in res)
    assert sim.pose[0] == pytest.approx(1.5 - R, abs=1e-5) and sim.pose[0] <= 1.5 - R + 1e-9
    assert sim.touching
    assert np.abs(sim.wheels).max() < 1e-5           # executed: the wheels could not turn
    # turning a little while pressed, then pushing again: the same contact, no new penalty
    res = _drive(sim, (-0.5, 0.5), 3) + _drive(sim, (VMAX, VMAX), 5)
    assert not any(r.collision for r in res)
    # turning in place at the wall: allowed, no new contact
    res = _drive(sim, (-0.8, 0.8), 30)
    assert not any(r.collision for r in res)
    heading = sim.pose[2]
    assert abs(wrap_angle(heading - 0.0)) > 1.0
    # drive away: moves, no contact; then turn back and hit again: a second -0.1
    x0 = sim.pose[0]
    sim.reset(start=(sim.pose[0], sim.pose[1], math.pi))
    res = _drive(sim, (1.0, 1.0), 5)
    assert sim.pose[0] < x0 - 0.2 and not sim.touching and sum(r.reward for r in res) == 0.0
    sim.reset(start=(sim.pose[0], sim.pose[1], 0.0))
    res = _drive(sim, (1.0, 1.0), 20)
    assert sum(r.collision for r in res) == 1


def test_box_contact_never_penetrates(params, arena):
    sim = Simulator(arena, params, np.random.default_rng(0))
    sim.reset('D')                                           # facing S1, 0.44 m away
    res = _drive(sim, (VMAX, VMAX), 30)
    assert sum(r.collision for r in res) == 1
    assert sim.pose[0] <= -0.65 - R + 1e-9
    assert sim.pose[0] == pytest.approx(-0.65 - R, abs=1e-5)
    # oblique push with turning: still never inside
    _drive(sim, (VMAX, 0.9), 40)
    # random driving everywhere: never inside anything
    rng = np.random.default_rng(7)
    sim.reset('random')
    for _ in range(3000):
        res = sim.step(rng.uniform(-VMAX, VMAX, 2) * np.array([1.0, rng.uniform(0.5, 1.0)]))
        assert sim.gap >= -1e-9
        if res.done:
            sim.reset('random')


def test_reaching_the_destination(params):
    sim = make_sim(params)
    sim.reset(start=(0.0, -0.5, math.pi / 2))
    rewards, res = [], None
    for _ in range(40):
        res = sim.step((0.5, 0.5))
        rewards.append(res.reward)
        if res.done:
            break
    assert res.reached and res.done and not res.timeout and not res.collision
    assert rewards[-1] == 1.0 and all(r == 0.0 for r in rewards[:-1])
    # 0.5 m at 0.5 m/s minus the 0.15 m goal radius: 0.7 s = 14 steps
    assert len(rewards) == 14 and res.t == pytest.approx(0.7)
    assert math.hypot(*sim.pose[:2]) <= 0.15
    with pytest.raises(RuntimeError, match='reset'):
        sim.step((0.0, 0.0))


def test_timeout_at_60_s(params):
    sim = make_sim(params)
    sim.reset('A')
    for k in range(1, 1201):
        res = sim.step((0.0, 0.0))
        assert res.reward == 0.0 and not res.reached and not res.collision
        if k < 1200:
            assert not res.done
    assert res.timeout and res.done and res.t == pytest.approx(60.0) and sim.t == res.t


# ------------------------------------------------------------------- laziness, resets

def test_step_does_not_sense(params, arena, monkeypatch):
    sim = Simulator(arena, params, np.random.default_rng(0))
    sim.reset('A')

    def boom(*args, **kwargs):
        raise AssertionError('sensor model computed')

    monkeypatch.setattr(sim_module.kernels, 'sense', boom)  # the sensor model's ray casts
    res = sim.step((0.3, 0.3))
    with pytest.raises(AssertionError):
        _ = res.obs
    monkeypatch.undo()
    assert res.obs.t == pytest.approx(DT)                     # computed on access
    assert res.obs is sim.observe()                           # cached for this step
    old = sim.step((0.3, 0.3))
    sim.step((0.3, 0.3))
    with pytest.raises(RuntimeError, match='moved on'):
        _ = old.obs
    eager = sim.step((0.3, 0.3), observe=True)
    sim.step((0.3, 0.3))
    assert eager.obs.t == pytest.approx(sim.t - DT)


def test_resets(params, arena):
    sim = Simulator(arena, params, np.random.default_rng(5))
    for name in arena.start_names:
        s = arena.start(name)
        sim.reset(name)
        assert sim.pose == pytest.approx([s.x, s.y, wrap_angle(s.heading)])
        assert sim.t == 0.0 and sim.wheels.tolist() == [0.0, 0.0] and not sim.done
    sim.reset('B', heading=0.25)
    assert sim.pose[2] == pytest.approx(0.25)
    dest = arena.destination
    for _ in range(50):
        sim.reset('random')
        x, y, _ = sim.pose
        assert sim.gap > 0.0 and math.hypot(x - dest.x, y - dest.y) > dest.goal_radius
    sim.reset('A')
    before = sim.pose
    obs = sim.reset('wander')
    after = sim.pose
    assert math.hypot(*(after[:2] - before[:2])) > 0.1     # it moved
    assert sim.gap >= 0.0 and sim.t == 0.0 and obs.t == 0.0
    assert math.hypot(after[0] - dest.x, after[1] - dest.y) > dest.goal_radius
    with pytest.raises(ValueError, match="no start 'Z'"):
        sim.reset('Z')
    with pytest.raises(ValueError, match='overlaps'):
        sim.reset(start=(1.45, 0.0, 0.0))


def test_wander_keeps_going_for_many_episodes(params, arena):
    sim = Simulator(arena, params, np.random.default_rng(11))
    sim.reset('A')
    poses = []
    for _ in range(20):
        sim.reset('wander')
        poses.append(sim.pose[:2])
        assert sim.gap >= 0.0
    spread = np.ptp(np.array(poses), axis=0)
    assert spread.min() > 0.3          # it explores, it does not stay stuck in a corner


# ------------------------------------------------------------------------- determinism

def _rollout(seed, params, arena, observe_every=1, n=300):
    sim = Simulator(arena, params, np.random.default_rng(seed))
    act = np.random.default_rng(seed + 1000)
    out = [sim.reset('random')]
    poses, flags = [], []
    for k in range(n):
        res = sim.step(act.uniform(-VMAX, VMAX, 2))
        flags.append((res.reward, res.collision, res.reached, res.timeout, res.t))
        poses.append(sim.pose)
        if observe_every and k % observe_every == 0:
            out.append(res.obs)
        if res.done:
            out.append(sim.reset('random'))
    return out, poses, flags, sim.reset('random')


def _same_obs(a: Observation, b: Observation) -> bool:
    return (a.t == b.t and np.array_equal(a.ir, b.ir)
            and np.array_equal(a.landmark_bearings, b.landmark_bearings, equal_nan=True)
            and (a.dest_bearing == b.dest_bearing
                 or (math.isnan(a.dest_bearing) and math.isnan(b.dest_bearing)))
            and np.array_equal(a.wheels, b.wheels))


def test_same_seed_same_rollout_different_seed_differs(params, arena):
    o1, p1, f1, _ = _rollout(42, params, arena)
    o2, p2, f2, _ = _rollout(42, params, arena)
    assert len(o1) == len(o2) and all(_same_obs(a, b) for a, b in zip(o1, o2))
    assert np.array_equal(np.array(p1), np.array(p2)) and f1 == f2
    o3, p3, _, _ = _rollout(43, params, arena)
    assert not np.array_equal(np.array(p1), np.array(p3))
    assert not all(_same_obs(a, b) for a, b in zip(o1, o3))


def test_observing_does_not_change_the_dynamics(params, arena):
    _, p1, f1, last1 = _rollout(9, params, arena, observe_every=1)
    _, p2, f2, last2 = _rollout(9, params, arena, observe_every=0)
    assert np.array_equal(np.array(p1), np.array(p2)) and f1 == f2
    assert last1.t == last2.t


# -------------------------------------------------------------------- arena validation

def test_arena_missing_key(tmp_path, params):
    for key in ('landmarks', 'destination', 'starts'):
        data = default_arena_data()
        del data[key]
        with pytest.raises(ArenaError, match=f'missing key {key}'):
            load_arena(write_yaml(tmp_path / f'no_{key}.yaml', data), R)
    data = default_arena_data()
    del data['destination']['goal_radius']
    with pytest.raises(ArenaError, match=r'missing key destination\.goal_radius'):
        load_arena(write_yaml(tmp_path / 'no_goal.yaml', data), R)
    data = default_arena_data()
    del data['tall_obstacles'][1]['size']
    with pytest.raises(ArenaError, match=r"tall_obstacles\[1\] \('T2'\)\.size"):
        load_arena(write_yaml(tmp_path / 'no_size.yaml', data), R)
    data = default_arena_data()
    data['starts']['C']['headnig_deg'] = 3.0
    with pytest.raises(ArenaError, match=r'unknown key starts\.C\.headnig_deg'):
        load_arena(write_yaml(tmp_path / 'typo.yaml', data), R)


def test_arena_obstacle_outside_the_walls(tmp_path):
    data = default_arena_data()
    data['short_obstacles'].append({'name': 'S9', 'center': [1.45, 0.0], 'size': [0.2, 0.2]})
    path = write_yaml(tmp_path / 'out.yaml', data)
    with pytest.raises(ArenaError, match=r"obstacle 'S9'.*outside the walls") as err:
        load_arena(path, R)
    assert str(path) in str(err.value)


def test_arena_start_or_destination_blocked(tmp_path):
    data = default_arena_data()
    data['starts']['D'] = {'x': -0.6, 'y': 0.0, 'heading_deg': 0.0}       # inside S1
    with pytest.raises(ArenaError, match=r"start 'D'.*short obstacle 'S1'"):
        load_arena(write_yaml(tmp_path / 'd.yaml', data), R)
    data = default_arena_data()
    data['starts']['A'] = {'x': 1.45, 'y': 1.0, 'heading_deg': 0.0}       # robot hits the wall
    with pytest.raises(ArenaError, match=r"start 'A'.*wall"):
        load_arena(write_yaml(tmp_path / 'a.yaml', data), R)
    data = default_arena_data()
    data['starts']['E'] = {'x': 0.6 - 0.1 - R + 0.01, 'y': -0.35, 'heading_deg': 0.0}  # T1
    with pytest.raises(ArenaError, match=r"start 'E'.*tall obstacle 'T1'"):
        load_arena(write_yaml(tmp_path / 'e.yaml', data), R)
    data = default_arena_data()
    data['tall_obstacles'][0]['center'] = [0.0, 0.0]
    with pytest.raises(ArenaError, match=r"destination.*'T1'"):
        load_arena(write_yaml(tmp_path / 'dest.yaml', data), R)


def test_arena_bad_values(tmp_path):
    for mutate, pattern in [
        (lambda d: d.update(size=-3.0), r'size = -3\.0 is out of range'),
        (lambda d: d['short_obstacles'][0].update(size=[0.0, 0.1]), r'S1.*size\[0\]'),
        (lambda d: d['landmarks'][0].update(x=2.0), r"landmark 'L1'.*outside"),
        (lambda d: d['landmarks'][0].update(x='far'), r'landmarks\[0\].*x.*number'),
        (lambda d: d['tall_obstacles'].append(dict(d['tall_obstacles'][0])), 'used twice'),
    ]:
        data = default_arena_data()
        mutate(data)
        with pytest.raises(ArenaError, match=pattern):
            load_arena(write_yaml(tmp_path / 'bad.yaml', data), R)
    with pytest.raises(ArenaError, match='no such file'):
        load_arena(tmp_path / 'missing.yaml', R)


def test_simulator_rejects_an_arena_too_tight_for_its_robot(params):
    data = copy.deepcopy(arena_dict())
    data['starts']['A'] = {'x': 1.35, 'y': 0.0, 'heading_deg': 0.0}   # 0.15 m from the wall
    a = parse_arena(data, robot_radius=0.1)
    big = load_sim_params(overrides={'robot.radius': 0.2})
    with pytest.raises(ArenaError, match="start 'A'"):
        Simulator(a, big, np.random.default_rng(0))


# ----------------------------------------------------------------- the paper's layout

def test_layout_counts(arena):
    assert len(arena.short_obstacles) == 4 and len(arena.tall_obstacles) == 2
    assert len(arena.landmarks) == 4 and arena.start_names == ('A', 'B', 'C', 'D', 'E')
    assert arena.size == 3.0


def _segment_clearance(arena, name, boxes):
    s, d = arena.start(name), arena.destination
    return min(segment_box_distance((s.x, s.y), (d.x, d.y), b.lo, b.hi) for b in boxes)


def test_layout_situations(arena, exact):
    sim = Simulator(arena, exact, np.random.default_rng(0))
    d = arena.destination
    # A, B, C: destination visible and the robot's whole swept path is clear
    for name in 'ABC':
        assert sim.reset(name).dest_visible, name
        assert _segment_clearance(arena, name, arena.obstacles) >= R, name
    # D: destination visible, but the straight line crosses a short obstacle
    obs = sim.reset('D')
    assert obs.dest_visible
    s = arena.start('D')
    short = arena.box_array()[len(arena.tall_obstacles):]
    assert segments_blocked(s.x, s.y, np.array([[d.x, d.y]]), short)[0]
    assert _segment_clearance(arena, 'D', arena.tall_obstacles) >= R
    # E: a tall obstacle hides the destination
    assert not sim.reset('E').dest_visible
    s = arena.start('E')
    assert segments_blocked(s.x, s.y, np.array([[d.x, d.y]]), arena.box_array(tall_only=True))[0]
    # every start heads toward the destination (within 5 degrees)
    for name in 'ABCD':
        assert abs(sim.reset(name).dest_bearing) < math.radians(5)


def test_innate_head_straight_bumps_from_d(exact, arena):
    """The innate policy's idea (turn toward the destination, drive) collides from D only."""
    sim = Simulator(arena, exact, np.random.default_rng(0))
    outcome = {}
    for name in 'ABCD':
        obs = sim.reset(name)
        collided = reached = False
        for _ in range(400):
            b = obs.dest_bearing
            turn = 0.0 if math.isnan(b) else 0.6 * b
            res = sim.step((0.4 - turn, 0.4 + turn), observe=True)
            obs = res.obs
            collided |= res.collision
            if res.done:
                reached = res.reached
                break
        outcome[name] = (collided, reached)
    assert outcome['A'] == outcome['B'] == outcome['C'] == (False, True)
    assert outcome['D'][0] is True
