"""The robot node's pure core (cr_bridge.core.ros_robot) and what it adds to the bridge's cores:
the scan read as a profile's sectors, readings, the episode rules of a profile (reached by the
destination's apparent width or its range, collision by a sector), the command guard's twist
limits, staleness, the choice of cmd_vel's type and the topic names. No ROS."""

from __future__ import annotations

import math

from clis_base.params import ConfigError, build
from cr_bridge.core.episode import RobotEpisodes
from cr_bridge.core.ros_robot import (
    Freshness,
    Lockstep,
    RobotReader,
    Scan,
    SectorReader,
    choose_cmd_vel_type,
    clashes,
    episode_rules,
    finite_or_zero,
    robot_topic,
    scaled_arena,
    scaled_wander,
)
from cr_bridge.core.safety import CommandGuard
from cr_sim.core.arena import load_arena
from cr_sim.core.gate import EpisodeGate
from cr_sim.core.profile import RobotProfile, Topics, load_profile
from cr_sim.core.sim import load_sim_params
from cr_sim.core.wander import WanderParams
import numpy as np
import pytest

N_BLOBS = 5                                        # destination + L1..L4
UNSEEN = np.full(N_BLOBS, np.nan)


def lidar(ranges=5.0, n=360, angle_min=-math.pi, range_min=0.1, range_max=12.0, t=0.0):
    """A 360-degree scan, one ray per degree from angle_min."""
    r = np.full(n, ranges, dtype=float) if np.isscalar(ranges) else np.asarray(ranges, float)
    return Scan(t, angle_min, 2 * math.pi / n, range_min, range_max, r)


def ray(scan: Scan, deg: float) -> int:
    """The index of the ray at ``deg`` (scanner frame)."""
    return int(round((math.radians(deg) - scan.angle_min) / scan.angle_increment)) \
        % len(scan.ranges)


def with_episode(name: str, **episode) -> RobotProfile:
    """Profile ``name`` with some of its section episode replaced (validated again)."""
    from clis_base.params import as_dict
    data = as_dict(load_profile(name))
    data['colours'] = {'destination': 'magenta',
                       'landmarks': {n: c for n, c in (('L1', 'red'), ('L2', 'green'),
                                                        ('L3', 'blue'), ('L4', 'yellow'))}}
    for key, value in episode.items():
        if isinstance(value, dict):
            data['episode'][key].update(value)
        else:
            data['episode'][key] = value
    return build(RobotProfile, data)


def robot(profile: RobotProfile, start: str = 'here'):
    """The bridge's episode core and a reader with ``profile``'s rules, as the node makes
    them."""
    rules = episode_rules(profile, 0.05, 1.0, -0.1)
    reader = RobotReader(profile, rules.rule)
    episodes = RobotEpisodes(rules.episode, load_sim_params().wander, rules.contact,
                             rules.goal_radius, reader.sectors.angles, EpisodeGate(),
                             np.random.default_rng(0), start, goal_width=rules.goal_width)
    return episodes, reader


def blobs(dest_bearing=math.nan, dest_width=math.nan):
    b, w = UNSEEN.copy(), UNSEEN.copy()
    b[0], w[0] = dest_bearing, dest_width
    return b, w


# ---------------------------------------------------------------- sectors


def test_the_cr_profile_reads_the_simulators_ir_scan_as_it_is():
    """The simulator's ir LaserScan (7 beams, -90..90 deg, from the surface): each sector is
    its beam, and nothing in range reads the IR range."""
    p = load_profile('cr')
    ir = np.array([0.5, 0.31, 0.12, 0.05, 0.5, 0.44, 0.2])
    scan = Scan(0.0, -math.pi / 2, math.pi / 6, 0.0, 0.5, ir)
    assert SectorReader(p.scan, p.body.radius).read(scan).tolist() == ir.tolist()


def test_a_sector_reads_the_nearest_valid_return_in_its_cone_from_the_surface():
    p = load_profile('husky')                      # 10-degree cones, radius 0.6, from centre
    s = SectorReader(p.scan, p.body.radius)
    scan = lidar(5.0)
    assert s.read(scan).tolist() == [1.67] * 7, 'nothing within range_max'
    r = scan.ranges
    r[ray(scan, 4.0)] = 1.0                        # in the front cone (+-5 deg)
    r[ray(scan, 3.0)] = 1.2
    r[ray(scan, 6.0)] = 0.7                        # outside it
    r[ray(scan, -30.0)] = 0.05                     # below range_min: no return
    r[ray(scan, -29.0)] = math.nan
    r[ray(scan, -31.0)] = math.inf
    r[ray(scan, 60.0)] = 13.0                      # above the scan's range_max: no return
    r[ray(scan, 90.0)] = 0.5                       # inside the body: touching
    got = s.read(scan)
    assert got[3] == pytest.approx(0.4), 'the nearest in the cone, minus the radius'
    assert got[2] == 1.67 and got[5] == 1.67, 'invalid returns are no returns'
    assert got[6] == 0.0, 'at least 0'


def test_the_scanners_mounting_yaw_turns_its_rays_to_the_heading():
    """The TurtleBot 4's lidar is mounted with yaw 90 deg: its angle -90 is the heading."""
    p = load_profile('turtlebot4')
    s = SectorReader(p.scan, p.body.radius)
    scan = lidar(5.0)
    scan.ranges[ray(scan, -90.0)] = 0.2
    got = s.read(scan)
    assert got[3] == pytest.approx(0.2 - 0.171) and np.all(np.delete(got, 3) == 0.75)


def test_a_zero_width_sector_reads_the_nearest_ray_within_half_a_spacing():
    p = load_profile('cr')                         # width 0 at -90, -60, ..., 90
    s = SectorReader(p.scan, p.body.radius)
    coarse = Scan(0.0, -math.pi, math.radians(45.0), 0.0, 10.0, np.arange(8) * 0.01)
    got = s.read(coarse)
    # rays at -180, -135, ..., 135: -90 and 0 and 90 are rays; -60 -> -45 (15 < 22.5)
    assert got.tolist() == pytest.approx([0.02, 0.03, 0.03, 0.04, 0.05, 0.05, 0.06])
    narrow = Scan(0.0, -math.pi / 2, math.radians(1.0), 0.0, 10.0, np.array([0.1, 0.2]))
    assert s.read(narrow).tolist() == [0.1, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5], \
        'no ray within half a spacing: no return'


def test_range_at_a_bearing_is_the_nearest_rays_surface_distance():
    p = load_profile('turtlebot4')
    s = SectorReader(p.scan, p.body.radius)
    scan = lidar(5.0)
    scan.ranges[ray(scan, -90.0 + 20.0)] = 0.3     # 20 deg left of the heading
    assert s.range_at(scan, math.radians(20.0)) == pytest.approx(0.3 - 0.171)
    assert s.range_at(scan, math.radians(20.4)) == pytest.approx(0.3 - 0.171)
    assert s.range_at(scan, math.radians(21.0)) == pytest.approx(5.0 - 0.171)
    scan.ranges[ray(scan, -90.0 + 20.0)] = math.inf
    assert math.isnan(s.range_at(scan, math.radians(20.0))), 'no return'
    assert math.isnan(s.range_at(scan, math.nan)), 'not seen'


# ---------------------------------------------------------------- episodes


def test_the_destination_is_reached_by_its_apparent_width():
    """Rule 'size' (the Husky's 25 deg): a seen destination narrower goes on, at the width the
    episode ends with the goal reward, whatever the scan; a width without a bearing is not
    seen."""
    e, reader = robot(load_profile('husky'))
    scan = lidar(5.0)
    s = e.step(reader.reading(0.0, scan, 0.0, 0.0, *blobs()), 0.0)
    assert [ev.name for ev in s.events] == ['start']
    for k, width in enumerate((10.0, 24.9), 1):
        s = e.step(reader.reading(0.05 * k, scan, 0.0, 0.0, *blobs(0.1, math.radians(width))),
                   0.0)
        assert s.reward == 0.0 and not s.events, width
    s = e.step(reader.reading(0.15, scan, 0.0, 0.0, *blobs(math.nan, math.radians(40.0))), 0.0)
    assert not s.events, 'not seen'
    s = e.step(reader.reading(0.2, scan, 0.0, 0.0, *blobs(-0.3, math.radians(25.0))), 0.0)
    assert s.reward == 1.0 and [ev.name for ev in s.events] == ['reached']
    assert s.events[0].values['duration'] == pytest.approx(0.2)


def test_the_destination_is_reached_by_the_scans_range_in_its_bearing():
    """Rule 'range' (the TurtleBot 4's 0.1 m): the return in the destination's bearing."""
    e, reader = robot(load_profile('turtlebot4'))
    scan = lidar(5.0)
    e.step(reader.reading(0.0, scan, 0.0, 0.0, *blobs()), 0.0)
    scan.ranges[ray(scan, -90.0 + 30.0)] = 0.171 + 0.15      # 30 deg left, 0.15 m away
    s = e.step(reader.reading(0.05, scan, 0.0, 0.0, *blobs(math.radians(30.0))), 0.0)
    assert not s.events
    scan.ranges[ray(scan, -90.0 + 30.0)] = 0.171 + 0.09
    s = e.step(reader.reading(0.1, scan, 0.0, 0.0, *blobs(math.radians(-30.0))), 0.0)
    assert not s.events, 'the return is not in its bearing'
    s = e.step(reader.reading(0.15, scan, 0.0, 0.0, *blobs(math.radians(30.0))), 0.0)
    assert [ev.name for ev in s.events] == ['reached'] and s.reward == 1.0


def test_a_sector_below_the_collision_range_is_a_collision_once_per_contact():
    """The Husky's collision_range 0.05 m: -0.1 when a sector reads less, once while it
    stays, again after it cleared; a reading above the range is no contact."""
    e, reader = robot(load_profile('husky'))
    clear, near, edge = lidar(5.0), lidar(5.0), lidar(5.0)
    near.ranges[ray(near, -60.0)] = 0.6 + 0.049     # the right front sector
    edge.ranges[ray(edge, 0.0)] = 0.6 + 0.051
    e.step(reader.reading(0.0, clear, 0.0, 0.0, *blobs()), 0.0)
    rewards = [e.step(reader.reading(0.05 * k, scan, 0.0, 0.0, *blobs()), 0.0).reward
               for k, scan in enumerate((edge, near, near, clear, near), 1)]
    assert rewards == [0.0, -0.1, 0.0, 0.0, -0.1]


def test_a_collision_sector_behind_the_robot_is_a_collision_the_modules_do_not_read():
    """The Husky's episode.collision_sectors (behind it, 100 to 260 deg): a return there
    below the collision range is a collision (the reading's bump), once per contact, and the
    modules' seven sectors do not change; without collision sectors it is none."""
    e, reader = robot(load_profile('husky'))
    clear, behind, side = lidar(5.0), lidar(5.0), lidar(5.0)
    behind.ranges[ray(behind, 170.0)] = 0.6 + 0.04
    side.ranges[ray(side, 95.0)] = 0.6 + 0.04       # between the 90-deg cone and the rear
    r = reader.reading(0.0, behind, 0.0, 0.0, *blobs())
    assert r.bump == 1 and r.ir.tolist() == [1.67] * 7
    assert reader.reading(0.0, side, 0.0, 0.0, *blobs()).bump == 0
    e.step(reader.reading(0.0, clear, 0.0, 0.0, *blobs()), 0.0)
    rewards = [e.step(reader.reading(0.05 * k, scan, 0.0, 0.0, *blobs()), 0.0).reward
               for k, scan in enumerate((behind, behind, clear, behind), 1)]
    assert rewards == [-0.1, 0.0, 0.0, -0.1]
    e, reader = robot(with_episode('husky', collision_sectors=[]))
    e.step(reader.reading(0.0, clear, 0.0, 0.0, *blobs()), 0.0)
    assert reader.behind is None
    assert e.step(reader.reading(0.05, behind, 0.0, 0.0, *blobs()), 0.0).reward == 0.0


def test_the_profiles_time_limit_and_wander_time():
    e, reader = robot(with_episode('husky', time_limit=1.0, wander_time=0.5))
    scan = lidar(5.0)
    names = [(k, ev.name) for k in range(0, 40)
             for ev in e.step(reader.reading(0.05 * k, scan, 0.0, 0.0, *blobs()), 0.0).events]
    assert names == [(0, 'start'), (20, 'timeout'), (31, 'start')], \
        'timeout after 1 s, the next start after a 0.5 s wander'


def test_readings_carry_the_sectors_the_wheels_of_the_twist_and_the_blobs():
    p = load_profile('husky')
    reader = RobotReader(p, 'size')
    b = np.array([0.1, 0.2, np.nan, 0.4, 0.5])
    w = np.array([0.3, np.nan, np.nan, 0.1, 0.1])
    r = reader.reading(2.5, lidar(5.0), 0.5, 1.0, b, w)
    assert r.t == 2.5 and r.ir.tolist() == [1.67] * 7
    assert r.wheels.tolist() == pytest.approx([0.5 - 0.2775, 0.5 + 0.2775])
    assert r.dest_bearing == 0.1 and r.dest_width == 0.3 and math.isnan(r.dest_distance)
    assert np.array_equal(r.landmark_bearings, b[1:], equal_nan=True)


def test_rule_size_by_pixel_area_only_is_refused_naming_the_key():
    p = with_episode('husky', reached={'width_deg': 0.0, 'area_px': 50})
    with pytest.raises(ConfigError, match=r'episode\.reached\.area_px.*width_deg above 0'):
        episode_rules(p, 0.05, 1.0, -0.1)


# ---------------------------------------------------------------- safety


def test_the_guard_clips_to_the_bodys_twist_limits_and_rejects_non_finite():
    """The Husky: v_max 1 m/s, omega_max 1 rad/s, no wheel limit (wheel base 0.555 m)."""
    g = CommandGuard(math.inf, 0.5, 0.555, 1.0, 1.0)
    u = np.array((0.2, 0.4))
    assert g.command(u, 0.0) and g.output(0.1).tolist() == u.tolist() and g.clamped == 0
    assert g.command((2.0, 2.0), 0.1) and g.output(0.1).tolist() == [1.0, 1.0]
    assert g.command((-1.0, 1.0), 0.2)
    assert g.output(0.2).tolist() == pytest.approx([-0.2775, 0.2775]) and g.clamped == 2
    for bad in ((math.nan, 0.0), (0.0, -math.inf)):
        assert not g.command(bad, 0.3) and g.output(0.3).tolist() == [0.0, 0.0]
    assert g.output(0.81).tolist() == [0.0, 0.0], 'the watchdog'
    assert g.limit((3.0, 1.0)).tolist() == pytest.approx([1.2775, 0.7225])
    assert g.limit((math.nan, 0.1)).tolist() == [0.0, 0.1]
    # the bridge's guard (no twist limits) is the wheel clamp alone
    cr = CommandGuard(1.3, 0.15)
    assert cr.limit((2.0, -0.4)).tolist() == [1.3, -0.4]


def test_the_last_check_before_a_command_zeroes_a_non_finite_one():
    assert finite_or_zero((0.1, -0.2)).tolist() == [0.1, -0.2]
    assert finite_or_zero((math.nan, 0.2)).tolist() == [0.0, 0.0]
    assert finite_or_zero((math.inf,)).tolist() == [0.0, 0.0]


def test_inputs_are_stale_when_never_seen_too_old_or_from_the_future():
    f = Freshness(('odom', 'scan', 'camera'), 0.5)
    assert f.stale(0.0) == ('odom', 'scan', 'camera') and f.never() == f.stale(0.0)
    for name in ('odom', 'scan', 'camera'):
        f.seen(name, 1.0)
    assert f.stale(1.5) == ()
    f.seen('odom', 1.2)
    assert f.stale(1.5001) == ('scan', 'camera')
    assert f.stale(0.9) == ('odom', 'scan', 'camera'), 'the clock went back'
    f.forget()
    assert f.never() == ('odom', 'scan', 'camera')


# ---------------------------------------------------------------- names and types


def test_cmd_vel_type_from_the_setting_or_the_robots_subscribers():
    twist, stamped = 'geometry_msgs/msg/Twist', 'geometry_msgs/msg/TwistStamped'
    assert choose_cmd_vel_type('Twist', [stamped]) == ('Twist', '')
    assert choose_cmd_vel_type('TwistStamped', []) == ('TwistStamped', '')
    assert choose_cmd_vel_type('auto', []) == (None, '')
    assert choose_cmd_vel_type('auto', [twist, twist]) == ('Twist', '')
    assert choose_cmd_vel_type('auto', [stamped]) == ('TwistStamped', '')
    kind, why = choose_cmd_vel_type('auto', [twist, stamped])
    assert kind is None and 'both' in why
    kind, why = choose_cmd_vel_type('auto', ['std_msgs/msg/String'])
    assert kind is None and 'std_msgs/msg/String' in why
    with pytest.raises(ValueError, match='cmd_vel_type'):
        choose_cmd_vel_type('twist', [])


def test_robot_topics_are_absolute_under_the_profiles_namespace():
    t = Topics('cmd_vel', 'auto', 'odom', '/base/scan', 'image_raw', '', '')
    assert [robot_topic(t, k) for k in ('cmd_vel', 'odom', 'scan')] == \
        ['/cmd_vel', '/odom', '/base/scan']
    t = Topics('cmd_vel', 'auto', 'odom', '/base/scan', 'image_raw', '', 'robot1')
    assert [robot_topic(t, k) for k in ('cmd_vel', 'odom', 'scan')] == \
        ['/robot1/cmd_vel', '/robot1/odom', '/base/scan']


def test_a_robot_topic_that_is_an_interface_topic_is_a_clash():
    robot = {'odom': '/odom', 'scan': '/ir', 'cmd_vel': '/cmd_vel'}
    assert clashes(robot, ['/odom', '/ir', '/cmd_vel', '/wheels']) == \
        ['odom: /odom', 'scan: /ir', 'cmd_vel: /cmd_vel']
    assert clashes(robot, ['/clis/odom', '/clis/ir', '/clis/cmd_vel']) == []


def test_the_arena_at_the_profiles_size():
    arena = load_arena(robot_radius=0.0)
    assert scaled_arena(arena, 1.0) is arena
    big = scaled_arena(arena, 10.0 / 3.0)
    assert big.size == pytest.approx(10.0)
    assert big.destination.goal_radius == pytest.approx(arena.destination.goal_radius * 10 / 3)
    assert [c for m in big.landmarks for c in (m.x, m.y)] == pytest.approx(
        [c * 10 / 3 for m in arena.landmarks for c in (m.x, m.y)])
    assert big.short_obstacles[0].size == pytest.approx(
        tuple(v * 10 / 3 for v in arena.short_obstacles[0].size))


def test_the_wander_moves_the_robot_the_same_share_of_a_bigger_arena():
    cr = WanderParams(speed=0.3, turn_speed=0.3, avoid_distance=0.12, front_deg=30.0,
                      steer_sigma=0.02, steer_max=0.1)
    assert scaled_wander(cr, 1.0, 1.3) == cr, "the CR's arena: the simulator's wander as it is"
    husky = scaled_wander(cr, 10.0 / 3.0, 1.0)
    assert (husky.speed, husky.turn_speed) == (1.0, 1.0), 'x 10/3, at most v_max'
    assert husky.avoid_distance == pytest.approx(0.4)
    assert (husky.steer_sigma, husky.steer_max) == pytest.approx((0.2 / 3, 1.0 / 3))
    assert husky.front_deg == 30.0, 'angles do not scale'
    assert scaled_wander(cr, 10.0, 0.0).speed == pytest.approx(3.0), 'v_max 0: no limit'


def test_lockstep_reads_a_frame_once_its_inputs_are_in_and_waits_at_decision_instants():
    """Lockstep (a robot that holds its clock until the frame's command): a frame is the
    camera's stamp once odometry and scan of it are in, after the frame read last; within an
    episode started at t0 the frames at t0 + l tau_i wait for the decision, the others and all
    frames between episodes are answered at once; without periods every frame of an episode
    waits."""
    lock = Lockstep([0.25, 0.5, 1.2], 0.05)
    assert Lockstep.frame(1.0, 1.0, 1.0, 0.95) == 1.0
    assert Lockstep.frame(1.0, 0.95, 1.0, 0.95) is None, 'its odometry not in yet'
    assert Lockstep.frame(1.0, 1.0, 0.95, 0.95) is None, 'its scan not in yet'
    assert Lockstep.frame(1.0, 1.05, 1.0, 1.0) is None, 'read already'
    t0 = 3.1
    waits = [k for k in range(40) if lock.waits(round(t0 + 0.05 * k, 9), t0, True)]
    assert waits == [0, 5, 10, 15, 20, 24, 25, 30, 35], waits       # 0.25 s and 1.2 s
    assert not any(lock.waits(t0 + 0.05 * k, t0, False) for k in range(40))
    assert not lock.waits(t0 + 0.025, t0, True), 'off the tick grid: no module decides'
    every = Lockstep([0.0], 0.05)
    assert all(every.waits(t0 + 0.05 * k, t0, True) for k in range(10))


def test_a_run_that_goes_on_numbers_its_episodes_from_the_first_episode():
    """``first_episode`` (clis run --resume): the robot's first start after it is that
    episode, the next ones follow."""
    p = load_profile('cr')
    rules = episode_rules(p, 0.05, 1.0, -0.1)
    reader = RobotReader(p, rules.rule)
    episodes = RobotEpisodes(rules.episode, load_sim_params().wander, rules.contact,
                             rules.goal_radius, reader.sectors.angles, EpisodeGate(),
                             np.random.default_rng(0), 'here', goal_width=rules.goal_width,
                             first_episode=41)
    scan = Scan(0.0, -math.pi / 2, math.pi / 6, 0.0, 0.5, np.full(7, 0.5))
    starts = []
    t = 0.0
    while len(starts) < 2:
        step = episodes.step(reader.reading(t, scan, 0.0, 0.0, *blobs()), t)
        starts += [int(ev.values['episode']) for ev in step.events if ev.name == 'start']
        t = round(t + 0.05, 9)
    assert starts == [41, 42]


def test_in_lockstep_the_next_start_waits_at_its_frame_for_the_learner():
    """``step(hold=True)`` (a robot in lockstep): once the wander time is over, a learner that
    has not reported the last episode holds the frame (no wander draw, nothing else), and the
    same frame starts the episode once it reports; the starts and the wander's draws are
    those of a learner that reported in time, however late it reports."""
    p = load_profile('cr')
    rules = episode_rules(p, 0.05, 1.0, -0.1)
    reader = RobotReader(p, rules.rule)
    scan = Scan(0.0, -math.pi / 2, math.pi / 6, 0.0, 0.5, np.full(7, 0.5))

    def run(late: int) -> tuple[list[float], list[list[float]], int]:
        """Two episodes (time limit) with a learner that reports ``late`` tries after the
        frame its start waits for."""
        gate = EpisodeGate(wait_for_learner=True)
        eps = RobotEpisodes(rules.episode, load_sim_params().wander, rules.contact,
                            rules.goal_radius, reader.sectors.angles, gate,
                            np.random.default_rng(3), 'wander', goal_width=rules.goal_width)
        starts, wander, held, t, ended = [], [], 0, 0.0, 0
        while len(starts) < 2:
            r = reader.reading(t, scan, 0.0, 0.0, *blobs())
            for tries in range(late + 1):
                if tries == late or late == 0:
                    gate.on_progress(ended, ended)
                step = eps.step(r, t, hold=True)
                if not step.held:
                    break
                assert not step.events and step.wander is None and step.reward is None
                held += 1
            else:
                raise AssertionError('the learner reported and the frame is still held')
            for ev in step.events:
                if ev.name == 'start':
                    starts.append(t)
                else:
                    ended = int(ev.values['episode'])
            if step.wander is not None:
                wander.append(step.wander.tolist())
            t = round(t + 0.05, 9)
        return starts, wander, held

    in_time = run(0)
    assert in_time[2] == 0
    for late in (1, 4):
        starts, wander, held = run(late)
        assert held == 2 * late, 'the first start and the next wait'
        assert (starts, wander) == in_time[:2]
    # without hold (a real robot) the robot wanders on until the learner reports
    gate = EpisodeGate(wait_for_learner=True)
    eps = RobotEpisodes(rules.episode, load_sim_params().wander, rules.contact,
                        rules.goal_radius, reader.sectors.angles, gate,
                        np.random.default_rng(3), 'wander', goal_width=rules.goal_width)
    steps = [eps.step(reader.reading(0.05 * k, scan, 0.0, 0.0, *blobs()), 0.0)
             for k in range(200)]
    assert all(s.wander is not None and not s.held for s in steps)
