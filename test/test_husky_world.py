"""The Husky example world (examples/husky_world): the PyBullet core without ROS (scan, camera,
drive, odometry, safety), then the node with real rclpy and Fast DDS (topics, types, QoS,
sim-time stamps, cmd_vel)."""

from __future__ import annotations

import math

from clis_base.params import ConfigError, build
from geometry_msgs.msg import TwistStamped
from husky_world import world as hw
from husky_world.conversions import from_time
from husky_world.world import PHYSICS_HZ, POST_HEIGHT, Every, HuskyWorld, HuskyWorldParams
from husky_world.world_node import FrameHold
from matplotlib.colors import rgb_to_hsv
from nav_msgs.msg import Odometry
import numpy as np
import pytest
from rclpy.qos import ReliabilityPolicy, qos_profile_sensor_data
from ros_util import Probe, start_node, stop
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, Image, LaserScan

HALF = 5.0                      # [m] the default arena (3 m scaled to 10 m): walls at +-5


def make(**values) -> HuskyWorld:
    """A world of the given parameters (validated as the node validates them)."""
    return HuskyWorld(build(HuskyWorldParams, values))


def run_for(w: HuskyWorld, seconds: float) -> None:
    w.step(round(seconds * PHYSICS_HZ))


def hue_mask(rgb: np.ndarray, hue_deg: float, tol_deg: float = 15.0) -> np.ndarray:
    """Pixels of ``rgb`` (H, W, 3) within ``tol_deg`` of ``hue_deg``, saturation > 0.5 and
    value > 0.2: the colour a blob detector would call by that name."""
    hsv = rgb_to_hsv(rgb.astype(float) / 255.0)
    dh = np.abs((hsv[..., 0] * 360.0 - hue_deg + 180.0) % 360.0 - 180.0)
    return (dh <= tol_deg) & (hsv[..., 1] > 0.5) & (hsv[..., 2] > 0.2)


# ------------------------------------------------------------------------------ the core


def test_scan_reads_the_walls_and_obstacle_at_their_ranges():
    # at (3.5, 0) heading north: the north wall ahead, the east wall on the right, and short
    # obstacle S3 (x in [2.33, 2.67] scaled) on the left
    with make(start='', x=3.5, y=0.0, yaw=math.pi / 2, range_max=8.0) as w:
        run_for(w, 0.25)
        x, y, yaw = w.pose()
        assert abs(yaw - math.pi / 2) < 0.01
        angles, ranges = w.scan_angles, w.scan()
        assert len(ranges) == 360                         # all around, a ray per degree
        assert angles[0] == pytest.approx(-math.pi)
        assert angles[-1] == pytest.approx(math.pi - math.radians(1.0))
        assert angles[180] == pytest.approx(0.0, abs=1e-12)
        assert ranges[180] == pytest.approx(HALF - y, abs=0.03)           # north wall
        assert ranges[90] == pytest.approx(HALF - x, abs=0.03)            # east wall
        assert ranges[270] == pytest.approx(x - 0.8 * 10 / 3, abs=0.03)   # S3's east face
        assert ranges[0] == pytest.approx(HALF + y, abs=0.03)             # behind: south wall
        assert np.all(np.isinf(ranges) | (ranges <= w.params.range_max))
    with make(start='', x=3.5, y=0.0, yaw=math.pi / 2, range_max=4.0) as w:
        assert w.scan()[180] == math.inf, 'nothing within range_max'


def test_scan_never_sees_the_robot_itself(monkeypatch):
    # a lidar inside the chassis (0.30 m high) reads what one above it (0.42 m) reads: the
    # rays pass through the robot's own links (walls and obstacles are taller than both)
    with make() as w:
        run_for(w, 0.25)
        above = w.scan()
        monkeypatch.setattr(hw, 'LIDAR_HEIGHT', 0.30)
        inside = w.scan()
    assert np.isfinite(above).sum() > 20
    np.testing.assert_allclose(inside, above, atol=0.01)


def test_the_camera_never_sees_the_robots_own_meshes_which_are_not_drawn():
    # driving, turning, braking and reversing (the chassis pitches and rolls): each frame is
    # the same with the robot's meshes drawn, which the world leaves out to save their cost
    with make(width=160, height=120) as w:
        alphas = [v[7][3] for v in w._c.getVisualShapeData(w.robot)]
        assert alphas and max(alphas) == 0.0, 'not drawn by default'
        for k in range(12):
            w.set_command(1.0 if k < 8 else -1.0, 0.8 if k % 4 < 2 else -0.8)
            run_for(w, 0.25)
            left_out = w.image()
            w.show_robot(True)
            drawn = w.image()
            w.show_robot(False)
            np.testing.assert_array_equal(left_out, drawn)
        w.show_robot(True)
        assert min(v[7][3] for v in w._c.getVisualShapeData(w.robot)) > 0.0


def test_image_shows_the_red_landmark_where_the_pinhole_projects_it():
    # L1 (red) stands on the east wall at (5.0, 2.5); the robot looks east, 0.2 rad to the right
    with make(start='', x=1.5, y=2.0, yaw=-0.2) as w:
        run_for(w, 0.1)
        rgb = w.image()
        k = w.intrinsics
        assert rgb.shape == (k.height, k.width, 3) and rgb.dtype == np.uint8
        u, v_mid = w.project(np.array((5.0, 2.5, 0.5 * POST_HEIGHT)))
        assert 40 < u < 130, 'the post is well off the image centre'
        red = hue_mask(rgb, 0.0)
        assert red.sum() > 100, 'the red post is in view'
        cols = np.nonzero(red)[1]
        assert abs(cols.mean() - u) < 1.0, (cols.mean(), u)
        assert cols.max() - cols.min() < 20, 'one post, no other red'
        # the post's column, from 0.3 m to 0.9 m up: every pixel red in HSV terms
        _, v_top = w.project(np.array((5.0, 2.5, 0.9)))
        _, v_low = w.project(np.array((5.0, 2.5, 0.3)))
        column = red[int(math.ceil(v_top)):int(v_low), int(round(u))]
        assert len(column) > 10 and column.all()


def test_destination_post_is_magenta_ahead_of_start_a():
    with make() as w:                               # start A faces the destination
        rgb = w.image()
        u, _ = w.project(np.array((0.0, 0.0, 0.5 * POST_HEIGHT)))
        magenta = hue_mask(rgb, 300.0)
        assert magenta.sum() > 50
        assert abs(np.nonzero(magenta)[1].mean() - u) < 1.0
        assert not hue_mask(rgb, 0.0).any(), 'no red in view from A'


@pytest.mark.parametrize(('name', 'hue', 'post', 'pose'), [
    ('L2 green', 120.0, (-2.5, HALF), (-2.5, 2.0, math.pi / 2)),
    ('L3 blue', 240.0, (-HALF, -2.5), (-1.5, -1.5, math.atan2(-1.0, -3.5))),
    ('L4 yellow', 60.0, (2.5, -HALF), (3.5, -2.5, math.atan2(-2.5, -1.0))),
])
def test_every_landmark_keeps_its_hue(name, hue, post, pose):
    with make(start='', x=pose[0], y=pose[1], yaw=pose[2]) as w:
        rgb = w.image()
        u, _ = w.project(np.array((*post, 0.5 * POST_HEIGHT)))
        mask = hue_mask(rgb, hue)
        assert mask.sum() > 100, name
        assert abs(np.nonzero(mask)[1].mean() - u) < 1.0, name


def edge_margin(x: float) -> float:
    return abs(x - round(x))


def test_camera_info_projects_box_edges_to_the_pixel():
    # a pixel i shows the scene at i (ROS convention): the intrinsics put an edge between the
    # right two pixels, where half a pixel of principal point would move it by one
    with make(start='', x=3.5, y=-3.0, yaw=2.203) as w:      # tall obstacle T1 against the sky
        run_for(w, 0.25)
        rgb = w.image()
        xs, ys = (5 / 3, 7 / 3), (-1.5, -2.5 / 3)               # T1 scaled: x, y spans
        us = [w.project(np.array((x, y, 1.2)))[0] for x in xs for y in ys]
        row = int(round(w.project(np.array((2.0, -1.2, 1.2)))[1]))
        assert min(edge_margin(u) for u in (min(us), max(us))) > 0.1
        dark = np.nonzero(rgb[row].max(axis=1) < 120)[0]
        assert (dark.min(), dark.max()) == (math.ceil(min(us)), math.floor(max(us)))
    with make(start='', x=3.5, y=-0.12, yaw=math.pi / 2) as w:  # the north wall's top edge
        run_for(w, 0.25)
        rgb = w.image()
        u, v_top = w.project(np.array((3.5, HALF, 0.8)))
        assert edge_margin(v_top) > 0.1
        sky = np.nonzero(rgb[:, int(round(u))].min(axis=1) > 250)[0]
        assert sky.max() == math.floor(v_top)


def test_camera_intrinsics_follow_the_field_of_view():
    with make() as w:
        k = w.intrinsics
        assert (k.fx, k.fy, k.cx, k.cy) == (pytest.approx(160.0), pytest.approx(160.0), 160.0,
                                            119.0)
    with make(width=640, height=480, hfov_deg=60.0) as w:
        assert w.intrinsics.fx == pytest.approx(320.0 / math.tan(math.radians(30.0)))
        assert w.image().shape == (480, 640, 3)


def test_forward_command_moves_the_odometry_v_t():
    with make() as w:
        x0, y0, yaw0 = w.pose()
        for _ in range(20):                         # a 10 Hz controller for 2 s
            w.set_command(0.5, 0.0)
            run_for(w, 0.1)
        odom = w.odom()
        assert odom.x == pytest.approx(1.0, rel=0.15)
        assert abs(odom.y) < 0.05 and abs(odom.yaw) < 0.05
        assert odom.v == pytest.approx(0.5, abs=0.02)
        x1, y1, _ = w.pose()
        moved = math.hypot(x1 - x0, y1 - y0)
        assert moved == pytest.approx(odom.x, rel=0.15)
        assert math.atan2(y1 - y0, x1 - x0) == pytest.approx(yaw0, abs=0.05)


def test_turn_command_turns_the_body_with_some_slip():
    with make() as w:
        yaw0 = w.pose()[2]
        for _ in range(20):
            w.set_command(0.0, 0.5)
            run_for(w, 0.1)
        odom = w.odom()
        turned = math.remainder(w.pose()[2] - yaw0, 2 * math.pi)
    assert odom.yaw == pytest.approx(1.0, rel=0.05)     # what the wheels did
    assert 0.75 <= turned <= 1.05, turned               # what the skid-steer body did


def test_wheels_stop_half_a_second_after_the_last_command():
    with make() as w:
        w.set_command(0.5, 0.0)
        run_for(w, 0.45)
        assert w.odom().v == pytest.approx(0.5, abs=0.03)
        assert w.command == (0.5, 0.0)
        run_for(w, 0.15)                            # 0.5 s: the timeout; 0.1 s to stop
        assert w.command == (0.0, 0.0)
        assert abs(w.odom().v) < 0.02
        x, y, _ = w.pose()
        run_for(w, 0.5)
        assert math.hypot(w.pose()[0] - x, w.pose()[1] - y) < 0.01


def test_non_finite_commands_drive_at_zero():
    with make() as w:
        x0, y0, _ = w.pose()
        assert not w.set_command(math.nan, 0.0)
        run_for(w, 1.0)
        assert math.hypot(w.pose()[0] - x0, w.pose()[1] - y0) < 0.01
        assert abs(w.odom().x) < 0.01
        assert w.set_command(0.5, 0.0)
        run_for(w, 0.3)
        assert w.odom().v > 0.4
        assert not w.set_command(0.2, math.inf)     # a bad command stops a moving robot
        assert w.command == (0.0, 0.0)
        run_for(w, 0.1)
        assert abs(w.odom().v) < 0.02
        assert w.rejected == 2


def test_commands_are_clipped_to_the_limits():
    with make() as w:
        w.set_command(5.0, -3.0)
        assert w.command == (1.0, -1.0)
        w.set_command(-2.0, 0.25)
        assert w.command == (-1.0, 0.25)


def test_schedules_stamp_the_first_step_at_or_after_each_period():
    def steps(rate: float, n: int = 240) -> list[int]:
        every = Every(rate)
        return [s for s in range(n) if every.due(s)]
    assert steps(100.0)[:6] == [0, 3, 5, 8, 10, 12] and len(steps(100.0)) == 100
    assert steps(50.0)[:6] == [0, 5, 10, 15, 20, 24] and len(steps(50.0)) == 50
    assert steps(10.0) == list(range(0, 240, 24))
    assert steps(240.0) == list(range(240))


@pytest.mark.parametrize(('values', 'message'), [
    ({'size': 0.5}, r'size = 0\.5 is out of range: must be in \[1\.0, 100\.0\]'),
    ({'hfov_deg': 180.0}, r'hfov_deg = 180\.0 is out of range: must be in \[10\.0, 170\.0\]'),
    ({'scan_rays': 1}, r'scan_rays = 1 is out of range'),
    ({'start': 'Z'}, r"start = 'Z' is not a start of .*arena\.yaml: must be one of A, B, C, "),
    ({'start': '', 'x': 4.8}, r'x, y: the pose \(4\.800, 0\.000\) leaves no room'),
])
def test_bad_parameters_name_the_key(values, message):
    with pytest.raises(ConfigError, match=message):
        make(**values).close()


def test_frame_hold_waits_for_a_command_stamped_at_or_after_the_frame():
    hold = FrameHold(timeout=2.0, resend=0.2)
    assert hold.poll(0.0) == 'go', 'nothing held yet'
    assert hold.held_at(0.5, now=10.0)
    assert hold.poll(10.0) == 'wait'
    hold.on_command(0.45)                           # the answer to the previous frame
    assert hold.poll(10.1) == 'wait'
    assert hold.poll(10.21) == 'resend'             # every 0.2 s of wall time
    assert hold.poll(10.3) == 'wait'
    assert hold.poll(10.42) == 'resend'
    assert hold.poll(10.43) == 'wait'
    hold.on_command(0.5 - 2e-6)                     # just outside the tolerance
    assert hold.poll(10.44) == 'wait'
    hold.on_command(0.5 - 5e-7)                     # at t, within the tolerance
    assert hold.poll(10.45) == 'go' and hold.poll(10.46) == 'go'
    assert hold.timeouts == 0
    # a later stamp releases too, also one that came before the frame was published
    hold.held_at(0.55, now=11.0)
    hold.on_command(0.6)
    assert hold.poll(11.01) == 'go'
    hold.held_at(0.65, now=12.0)
    hold.on_command(0.6)
    assert hold.poll(12.0) == 'wait'


def test_frame_hold_runs_free_after_the_timeout_until_the_next_command():
    hold = FrameHold(timeout=2.0, resend=0.2)
    assert hold.held_at(0.0, now=0.0)               # t = 0: no command has ever come
    assert hold.poll(1.99) == 'resend'
    assert hold.poll(500.0) == 'resend', 'before the first command: no timeout'
    hold.on_command(0.0)                            # the controller is up
    assert hold.poll(500.0) == 'go'
    assert hold.held_at(0.05, now=500.0)
    assert hold.poll(501.99) == 'resend'
    assert hold.poll(502.0) == 'go' and hold.timeouts == 1
    assert not hold.held_at(0.1, now=502.1), 'free: the next frames are not held'
    assert hold.poll(502.1) == 'go'
    assert not hold.held_at(0.2, now=502.2)
    hold.on_command(0.05)                           # any command re-arms, an old stamp too
    assert hold.held_at(0.3, now=502.3)
    assert hold.poll(502.31) == 'wait'
    hold.on_command(0.3)
    assert hold.poll(502.32) == 'go' and hold.timeouts == 1
    assert hold.held_at(0.4, now=503.0)             # the timeout counts from each hold
    assert hold.poll(504.99) == 'resend'
    assert hold.poll(505.0) == 'go' and hold.timeouts == 2


# ------------------------------------------------------------------------------ the node

TOPICS = {'/clock', '/odom', '/scan', '/image_raw', '/camera_info'}


def stamp(msg) -> float:
    return from_time(msg.clock if isinstance(msg, Clock) else msg.header.stamp)


def on_step_grid(t: float) -> bool:
    return abs(t * PHYSICS_HZ - round(t * PHYSICS_HZ)) < 1e-6


@pytest.fixture
def probe():
    p = Probe('husky_probe')
    yield p
    p.close()


@pytest.mark.ros
def test_node_publishes_the_standard_topics_and_obeys_cmd_vel(probe):
    proc = start_node('husky_world.world_node', '-p', 'real_time_factor:=0.0')
    try:
        node = probe.node
        probe.listen(Clock, '/clock')
        probe.listen(Odometry, 'odom')
        for msg_type, topic in ((LaserScan, 'scan'), (Image, 'image_raw'),
                                (CameraInfo, 'camera_info')):
            node.create_subscription(msg_type, topic,
                                     lambda m, t=topic: probe.msgs[t].append(m),
                                     qos_profile_sensor_data)
        need = {'/clock': 20, 'odom': 10, 'scan': 3, 'image_raw': 3, 'camera_info': 3}
        assert probe.spin_until(lambda: all(len(probe.msgs[t]) >= n for t, n in need.items()),
                                60), ({t: len(probe.msgs[t]) for t in need}, stop(proc))

        # exactly the five topics out, cmd_vel in as TwistStamped
        def published() -> set[str]:
            return {name for name, _ in node.get_publisher_names_and_types_by_node(
                'husky_world', '/')} - {'/rosout', '/parameter_events'}
        assert probe.spin_until(lambda: published() == TOPICS, 10), published()
        # an endpoint can be discovered before its node's name (_NODE_NAME_UNKNOWN_)
        probe.spin_until(lambda: [s.node_name for s in node.get_subscriptions_info_by_topic(
            '/cmd_vel')] == ['husky_world'], 10)
        subs = node.get_subscriptions_info_by_topic('/cmd_vel')
        assert [(s.node_name, s.topic_type) for s in subs] == \
            [('husky_world', 'geometry_msgs/msg/TwistStamped')]
        for topic, reliability in (('/clock', ReliabilityPolicy.RELIABLE),
                                   ('/odom', ReliabilityPolicy.RELIABLE),
                                   ('/scan', ReliabilityPolicy.BEST_EFFORT),
                                   ('/image_raw', ReliabilityPolicy.BEST_EFFORT),
                                   ('/camera_info', ReliabilityPolicy.BEST_EFFORT)):
            infos = node.get_publishers_info_by_topic(topic)
            assert [i.qos_profile.reliability for i in infos] == [reliability], topic

        # sim-time stamps on the physics grid, increasing
        for topic in need:
            stamps = [stamp(m) for m in probe.msgs[topic]]
            assert all(on_step_grid(t) for t in stamps), topic
            assert all(b > a for a, b in zip(stamps, stamps[1:])), topic
        assert all(abs(t * 10 - round(t * 10)) < 1e-6 for t in
                   (stamp(m) for m in probe.msgs['image_raw'])), 'images on the 10 Hz grid'
        odom = probe.msgs['odom'][-1]
        assert (odom.header.frame_id, odom.child_frame_id) == ('odom', 'base_link')
        scan = probe.msgs['scan'][-1]
        assert scan.header.frame_id == 'lidar' and len(scan.ranges) == 360
        assert scan.angle_min == pytest.approx(-math.pi)
        assert scan.angle_min + 359 * scan.angle_increment == pytest.approx(scan.angle_max)
        assert scan.angle_max == pytest.approx(math.pi - math.radians(1.0))
        assert scan.range_max == 5.0
        finite = [r for r in scan.ranges if math.isfinite(r)]
        assert finite and all(scan.range_min <= r <= scan.range_max for r in finite)
        image = probe.msgs['image_raw'][-1]
        assert (image.width, image.height, image.encoding, image.step) == (320, 240, 'rgb8', 960)
        assert image.header.frame_id == 'camera' and len(image.data) == 320 * 240 * 3
        rgb = np.frombuffer(bytes(image.data), np.uint8).reshape(240, 320, 3)
        assert hue_mask(rgb, 300.0).sum() > 50, 'the destination ahead of start A'
        info = probe.msgs['camera_info'][-1]
        assert info.header.frame_id == 'camera' and (info.width, info.height) == (320, 240)
        assert list(info.k) == pytest.approx([160.0, 0, 160.0, 0, 160.0, 119.0, 0, 0, 1])
        assert list(info.p) == pytest.approx([160.0, 0, 160.0, 0, 0, 160.0, 119.0, 0, 0, 0, 1, 0])
        info_stamps = {stamp(m) for m in probe.msgs['camera_info']}
        assert any(stamp(m) in info_stamps for m in probe.msgs['image_raw']), \
            'an image and its camera_info share their stamp'

        # drive: TwistStamped at 50 Hz of wall time moves the odometry forward
        pub = node.create_publisher(TwistStamped, 'cmd_vel', 10)
        cmd = TwistStamped()
        cmd.twist.linear.x = 0.5
        n0 = len(probe.msgs['odom'])
        x0 = probe.msgs['odom'][-1].pose.pose.position.x

        def driven() -> bool:
            pub.publish(cmd)
            return probe.msgs['odom'][-1].pose.pose.position.x - x0 > 0.5
        assert probe.spin_until(driven, 30), probe.msgs['odom'][-1].pose.pose
        moving = probe.msgs['odom'][-1]
        speeds = [m.twist.twist.linear.x for m in probe.msgs['odom'][n0:]]
        assert max(speeds) == pytest.approx(0.5, abs=0.03), 'the commanded speed'
        assert abs(moving.pose.pose.position.y) < 0.05
        # no more commands: stopped by the timeout (0.5 s of sim time)
        t_last = stamp(moving)
        assert probe.spin_until(lambda: stamp(probe.msgs['odom'][-1]) > t_last + 1.5, 30)
        assert abs(probe.msgs['odom'][-1].twist.twist.linear.x) < 0.02
    finally:
        out = stop(proc)
    assert proc.returncode == 0 and 'Traceback' not in out, out


@pytest.mark.ros
def test_lockstep_holds_the_world_at_each_image_until_its_command(probe):
    # as fast as the CPU goes, yet the world steps on only when the controller has answered
    # the image: frame by frame, none skipped. Judged by the stamps, never by wall-clock rates.
    proc = start_node('husky_world.world_node', '-p', 'lockstep:=true',
                      '-p', 'command_timeout:=30.0', '-p', 'real_time_factor:=0.0',
                      '-p', 'image_rate:=20.0', '-p', 'scan_rate:=20.0',
                      '-p', 'odom_rate:=20.0')
    try:
        node = probe.node
        probe.listen(Clock, '/clock')
        images: list[Image] = []
        node.create_subscription(Image, 'image_raw', images.append, qos_profile_sensor_data)
        # no cmd_vel: held at the first image, which is re-sent (a late subscriber gets it)
        assert probe.spin_until(lambda: images, 60), stop(proc)
        first = stamp(images[0])
        probe.spin_for(1.0)
        # (re-sent every 0.2 s of wall time: judged by what arrived, however loaded the host)
        assert probe.spin_until(lambda: len(images) >= 2, 30)
        clocks = [stamp(m) for m in probe.msgs['/clock']]
        assert clocks and max(clocks) <= first + 1e-6, (first, max(clocks))
        assert len(images) >= 2 and {stamp(m) for m in images} == {first}, 'the held frame'

        # a controller that answers each image with a command stamped with the image's stamp
        pub = node.create_publisher(TwistStamped, 'cmd_vel', 10)

        def answer(img: Image) -> None:
            cmd = TwistStamped()
            cmd.header.stamp = img.header.stamp
            cmd.twist.linear.x = 0.2
            pub.publish(cmd)
        answer(images[-1])
        node.create_subscription(Image, 'image_raw', answer, qos_profile_sensor_data)
        assert probe.spin_until(lambda: len({stamp(m) for m in images}) >= 8, 60), \
            (sorted({stamp(m) for m in images}), stop(proc))
        seen = sorted({stamp(m) for m in images})
        assert seen[0] == first
        assert all(abs(b - a - 0.05) < 1e-6 for a, b in zip(seen, seen[1:])), seen
        # never more than one frame past the images answered
        assert max(stamp(m) for m in probe.msgs['/clock']) <= seen[-1] + 0.05 + 1e-6
    finally:
        out = stop(proc)
    assert proc.returncode == 0 and 'Traceback' not in out, out
