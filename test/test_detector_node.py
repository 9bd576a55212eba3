"""The colour-blob detector (clis_modules.core.detector, clis_modules.detector_node) and the
simulator's standard topics (cr_sim.standard_topics).

Pure: on frames rendered by cr_sim.core.render from known poses through the robot profiles'
cameras (the cr omni-camera strip, the husky pinhole by its field of view and by camera_info's
intrinsics) the detected bearings are the geometric ones within one pixel's angle and the
widths the silhouettes' within two; a target behind a tall obstacle or outside the field of
view is not seen; the image, camera_info, camera and scan messages carry what they should.
ROS: the node as a process reads rgb8 frames and camera_info published from here, answers each
frame with its stamp, drops an unsupported encoding with one error line and goes on; with its
image topic remapped and in a namespace of its own it reads the simulator's rendered frames
(StandardTopics) and gives the pure core's bearings.
"""

from __future__ import annotations

import dataclasses
import math
import time

from builtin_interfaces.msg import Time
from clis_modules.core.blobs import NAMED_RANGES, Blob, ColourRange, draw_boxes
from clis_modules.core.detector import Detector
from clis_modules.detector_node import absolute_topic, detector_of
from clis_modules.image_conversions import camera_info_k, camera_msg, image_array, image_msg
from cr_sim.core.arena import Box, load_arena
from cr_sim.core.camera import Panoramic, Pinhole
from cr_sim.core.geometry import wrap_angle
from cr_sim.core.profile import load_profile
from cr_sim.core.render import Scene, render
from cr_sim.core.sim import load_sim_params
from cr_sim.standard_topics import (
    StandardTopics,
    camera_info_msg,
    scan_layout,
    scan_msg,
)
from cr_sim.standard_topics import image_msg as sim_image_msg
import numpy as np
import pytest
import rclpy
from render_truth import truth
from ros_util import Probe, start_node, stop
from sensor_msgs.msg import CameraInfo, Image, JointState, LaserScan

from cr_sim import conversions as conv

R = 0.11                                    # the CR's radius (config/robot.yaml)
NAMES = ('destination', 'L1', 'L2', 'L3', 'L4')
#: Intrinsics for the husky's 320 x 240 frames, far from its 90 degree field of view (fx 160).
K = (240.0, 0.0, 170.0, 0.0, 240.0, 115.0, 0.0, 0.0, 1.0)
POSES = [(0.5, 0.5, 0.3), (-0.9, -1.1, 2.0), (1.0, -0.1, -2.5), (-0.3, 1.2, -1.2),
         (0.2, -0.5, 0.0), (-1.2, 0.9, -0.6)]
#: Behind tall obstacle T1 as seen from landmark L1, facing L1 (T1 stands in between).
BEHIND_T1 = (0.3467, -0.6596, math.radians(50.71))


@pytest.fixture(scope='module')
def arena():
    return load_arena()


@pytest.fixture(scope='module')
def scene(arena):
    return Scene.from_arena(arena)


def detector(kind: str) -> Detector:
    """'cr': the omni-camera strip; 'husky': the pinhole by its field of view; 'husky-k': by
    the intrinsics K."""
    det = detector_of(load_profile(kind.split('-')[0]))
    if kind == 'husky-k':
        assert det.set_intrinsics(320, 240, K)
    return det



def in_view(camera, b: float, alpha: float) -> str:
    """'in': the whole silhouette is in the image; 'out': none of it; else 'edge'."""
    if isinstance(camera, Panoramic):
        return 'in'
    edges = np.isfinite(camera.column_of_bearing(np.array((b - alpha, b + alpha))))
    return 'in' if edges.all() else ('out' if not edges.any() else 'edge')


# ------------------------------------------------------------------------------------------
# the detector on rendered frames

@pytest.mark.parametrize('kind', ['cr', 'husky', 'husky-k'])
def test_bearings_and_widths_are_the_geometric_ones_within_a_pixel(arena, scene, kind):
    det = detector(kind)
    camera = det.camera(det.nominal.width, det.nominal.height)
    assert isinstance(camera, Panoramic if kind == 'cr' else Pinhole)
    if kind == 'husky-k':
        assert (camera.fx, camera.cx, camera.fy, camera.cy) == (240.0, 170.0, 240.0, 115.0)
    tally = {'seen': 0, 'not seen': 0}
    for pose in [tuple(s.pose) for s in arena.starts] + POSES + [BEHIND_T1]:
        assert arena.gap(pose[0], pose[1], R) > 0.0
        found = det.frame(render(scene, camera, pose), 'rgb8')
        assert found.names == NAMES and found.camera == camera
        geo = [truth(scene, pose, k) for k in range(len(NAMES))]
        for k, (name, tr) in enumerate(zip(NAMES, geo)):
            where = f'{kind}: {name} from {pose}: {tr}, {found.blobs[name]}'
            view = in_view(camera, tr['bearing'], tr['alpha'])
            crowded = any(abs(wrap_angle(o['bearing'] - tr['bearing']))
                          < o['alpha'] + tr['alpha'] + camera.angle_per_pixel
                          for j, o in enumerate(geo) if j != k)
            if tr['clear'] and view == 'in' and not crowded:
                err = wrap_angle(found.bearings[k] - tr['bearing'])
                assert abs(err) <= camera.angle_per_pixel, where
                assert found.widths[k] == pytest.approx(2 * tr['alpha'],
                                                        abs=2 * camera.angle_per_pixel), where
                tally['seen'] += 1
            elif tr['hidden'] or view == 'out':
                assert math.isnan(found.bearings[k]) and math.isnan(found.widths[k]), where
                tally['not seen'] += 1
    assert tally['seen'] >= 10 and tally['not seen'] >= (1 if kind == 'cr' else 10), tally


@pytest.mark.parametrize('kind', ['cr', 'husky'])
def test_a_landmark_behind_a_tall_obstacle_is_not_seen(arena, scene, kind):
    """From BEHIND_T1, T1 hides L1 straight ahead; without the tall obstacles L1 is seen
    there at its true bearing."""
    det = detector(kind)
    camera, k = det.nominal, NAMES.index('L1')
    tr = truth(scene, BEHIND_T1, k)
    assert tr['hidden'] and abs(tr['bearing']) < 0.01
    hidden = det.frame(render(scene, camera, BEHIND_T1), 'rgb8')
    assert math.isnan(hidden.bearings[k]) and hidden.blobs['L1'].area == 0
    bare = Scene.from_arena(dataclasses.replace(arena, tall_obstacles=()))
    shown = det.frame(render(bare, camera, BEHIND_T1), 'rgb8')
    assert abs(wrap_angle(shown.bearings[k] - tr['bearing'])) <= camera.angle_per_pixel
    # a tall box put across the line of sight from start A hides the destination too
    a = arena.start('A').pose
    wall = Box('W', (0.55, 0.55), (0.3, 0.05), True)
    walled = Scene.from_arena(dataclasses.replace(arena, tall_obstacles=(wall,)))
    assert not math.isnan(det.frame(render(scene, camera, a), 'rgb8').bearings[0])
    assert math.isnan(det.frame(render(walled, camera, a), 'rgb8').bearings[0])


def test_outside_the_pinholes_field_of_view_nothing_is_seen_the_strip_sees_all(arena, scene):
    """The husky's 90 degree view from start A: the destination ahead is seen, turned
    50 degrees away (more than 45 + its half-width) or behind it is not; the omni-camera
    sees it at every turn."""
    pin, pan = detector('husky'), detector('cr')
    x, y, th = arena.start('A').pose
    for turn, seen in ((0.0, True), (math.radians(40.0), True), (math.radians(50.0), False),
                       (math.radians(-50.0), False), (math.pi, False)):
        pose = (x, y, th + turn)
        b = pin.frame(render(scene, pin.nominal, pose), 'rgb8').bearings[0]
        assert math.isnan(b) != seen, turn
        if seen:
            assert abs(wrap_angle(b + turn)) <= pin.nominal.angle_per_pixel
        b = pan.frame(render(scene, pan.nominal, pose), 'rgb8').bearings[0]
        assert abs(wrap_angle(b + turn)) <= pan.nominal.angle_per_pixel


def test_intrinsics_win_over_the_field_of_view_for_their_size_only():
    det = detector('husky')
    nominal = det.camera(320, 240)
    assert nominal is det.nominal and not det.calibrated
    assert det.camera(160, 120).hfov == pytest.approx(nominal.hfov)    # another size: the fov
    assert det.set_intrinsics(320, 240, K) and not det.set_intrinsics(320, 240, K)
    assert det.camera(320, 240) == Pinhole.from_k(320, 240, K)
    assert det.camera(160, 120).hfov == pytest.approx(nominal.hfov)
    with pytest.raises(ValueError, match=r'^fx = 0\.0 is out of range'):
        det.set_intrinsics(320, 240, [0.0] * 9)                       # uncalibrated
    assert det.camera(320, 240) == Pinhole.from_k(320, 240, K), 'the model in force is kept'
    pan = detector('cr')
    assert not pan.set_intrinsics(360, 40, K) and pan.camera(360, 40) is pan.nominal
    wide = pan.camera(720, 80)                                         # a finer strip
    assert wide.angle_per_pixel == pytest.approx(math.pi / 360)
    assert wide.bearing_of_column(360) == pytest.approx(0.0)          # the heading: middle


def test_the_overlay_boxes_each_blob_in_its_colour_across_the_seam(scene):
    """The destination straight behind the robot straddles the strip's seam: its box is drawn
    at both ends; each seen target's box is in its colour, and nothing else changes."""
    det = detector('cr')
    img = render(scene, det.nominal, (0.0, 0.5, math.pi / 2))
    found = det.frame(img, 'rgb8')
    top, bottom, left, right = found.blobs['destination'].box
    assert left > right, 'across the seam'
    out = det.overlay(img, 'rgb8', found)
    changed = np.any(out != img, axis=2)
    assert changed.any()
    drawn = np.zeros_like(changed)
    for name, blob in found.blobs.items():
        if not blob.seen:
            continue
        t, b, lo, hi = blob.box
        cols = (lo - 1 + np.arange((hi - lo) % 360 + 3)) % 360
        rows = np.arange(max(t - 1, 0), min(b + 1, 39) + 1)
        edge = np.zeros_like(changed)
        edge[rows[[0, -1]][:, None], cols] = True
        edge[rows[:, None], cols[[0, -1]]] = True
        assert (out[edge] == det.colours[name]).all(), name
        drawn |= edge
    assert not (changed & ~drawn).any(), 'only the boxes are drawn'
    assert det.colours == {n: NAMED_RANGES[c].rgb() for n, c in zip(
        NAMES, ('magenta', 'red', 'green', 'blue', 'yellow'))}
    assert NAMED_RANGES['red'].rgb() == (255, 0, 0)
    assert ColourRange(100.0, 140.0).rgb() == (0, 255, 0)
    # a pinhole frame: a box at the image edge is cut there
    blob = Blob(True, 0.0, 4, 0.1, 0.5, (0, 1, 0, 1))
    edge = draw_boxes(np.zeros((4, 4, 3), np.uint8), {'x': blob}, {'x': (9, 9, 9)})
    assert (edge[:, :, 0] == [[9, 9, 9, 0], [9, 0, 9, 0], [9, 9, 9, 0], [0, 0, 0, 0]]).all()


# ------------------------------------------------------------------------------------------
# messages

def test_image_messages_round_trip_and_bad_frames_are_one_line_errors(scene):
    cam = detector('husky').nominal
    rgb = render(scene, cam, (0.3, 0.2, 1.0))
    stamp = Time(sec=12, nanosec=345)
    for msg in (image_msg(rgb, stamp, 'cam'), sim_image_msg(rgb, 12.000000345, 'cam')):
        assert (msg.encoding, msg.width, msg.height, msg.step) == ('rgb8', 320, 240, 960)
        assert msg.header.stamp == stamp and msg.header.frame_id == 'cam'
        np.testing.assert_array_equal(image_array(msg), rgb)
    # bgr8 with padded rows, rgba8
    padded = np.zeros((240, 1000), np.uint8)
    padded[:, :960] = rgb[..., ::-1].reshape(240, 960)
    bgr = Image(height=240, width=320, encoding='bgr8', step=1000, data=padded.tobytes())
    np.testing.assert_array_equal(image_array(bgr)[..., ::-1], rgb)
    det = detector('husky')
    want = det.frame(rgb, 'rgb8')
    np.testing.assert_array_equal(det.frame(image_array(bgr), 'bgr8').bearings, want.bearings)
    np.testing.assert_array_equal(det.overlay(image_array(bgr), 'bgr8', want),
                                  det.overlay(rgb, 'rgb8', want))
    bad = [(Image(height=240, width=320, encoding='mono16', step=640, data=bytes(240 * 640)),
            ["'mono16' is not supported", "'rgb8'", "'bgr8'", "'rgba8'"]),
           (Image(height=240, width=320, encoding='rgb8', step=960, data=bytes(960 * 239)),
            ['needs step >= 960 and 240 rows']),
           (Image(height=240, width=320, encoding='rgba8', step=960, data=bytes(960 * 240)),
            ['needs step >= 1280'])]
    for msg, parts in bad:
        with pytest.raises(ValueError) as info:
            image_array(msg)
        assert '\n' not in str(info.value) and all(p in str(info.value) for p in parts)


def test_camera_and_camera_info_messages():
    msg = camera_msg(NAMES, [0.5, math.nan, -3.0, 0.0, math.pi], [0.1, math.nan, 0.2, 0.3, 0.4],
                     Time(sec=3, nanosec=7), 'base_link')
    assert tuple(msg.name) == NAMES and msg.header.stamp == Time(sec=3, nanosec=7)
    assert msg.header.frame_id == 'base_link' and not msg.velocity
    np.testing.assert_array_equal(msg.position, [0.5, math.nan, -3.0, 0.0, math.pi])
    np.testing.assert_array_equal(msg.effort, [0.1, math.nan, 0.2, 0.3, 0.4])
    # the simulator's camera_info of a pinhole profile gives its model back
    cam = detector('husky').nominal
    info = camera_info_msg(cam, 1.5, 'base_link')
    width, height, k = camera_info_k(info)
    assert Pinhole.from_k(width, height, k) == cam
    assert info.distortion_model == 'plumb_bob' and list(info.d) == [0.0] * 5


def test_the_profiles_topics_resolve_absolute_under_their_namespace():
    cr, tb = load_profile('cr').topics, load_profile('turtlebot4').topics
    assert absolute_topic(cr, 'image') == '/image_raw' and absolute_topic(cr, 'camera_info') == ''
    assert absolute_topic(tb, 'camera_info') == '/oakd/rgb/preview/camera_info'
    spaced = dataclasses.replace(tb, namespace='robot1')
    assert absolute_topic(spaced, 'image') == '/robot1/oakd/rgb/preview/image_raw'
    assert absolute_topic(dataclasses.replace(tb, image='/cam/image'), 'image') == '/cam/image'


def test_the_scan_of_known_ir_readings():
    """The cr profile's scan is the simulator's ir LaserScan: 7 rays from -pi/2 by pi/6, the
    readings from the body surface, range_max the IR range; a centre-measuring profile adds
    the radius; sectors that are not the IR beams, or unevenly spaced, are refused."""
    sensors = load_sim_params().sensors
    ir = np.array([0.5, 0.123, 0.2, 0.0, 0.45, 0.5, 0.01])
    cr = load_profile('cr')
    layout = scan_layout(cr, sensors.ir_angles_deg)
    msg = scan_msg(ir, layout, 2.05, 'base_link')
    assert (msg.angle_min, msg.angle_increment, msg.angle_max) == pytest.approx(
        (-math.pi / 2, math.pi / 6, math.pi / 2), abs=1e-15)
    assert len(msg.ranges) == 7 and (msg.range_min, msg.range_max) == (0.0, 0.5)
    np.testing.assert_allclose(msg.ranges, ir, atol=1e-7)
    assert conv.from_time(msg.header.stamp) == 2.05
    assert msg == conv.ir_msg(ir, np.radians(sensors.ir_angles_deg), sensors.ir_range, 2.05,
                              'base_link')
    husky = load_profile('husky')
    wide = scan_msg(ir, scan_layout(husky, sensors.ir_angles_deg), 0.0, 'base_link')
    np.testing.assert_allclose(wide.ranges, ir + 0.6, atol=1e-6)
    assert wide.range_max == pytest.approx(husky.scan.range_max + 0.6)
    with pytest.raises(ValueError, match='7 IR readings for a scan of 6 rays'):
        scan_msg(ir, dataclasses.replace(layout, count=6), 0.0, 'base_link')
    with pytest.raises(ValueError, match='are not the IR beams'):
        scan_layout(cr, [-60.0, 0.0, 60.0])
    sectors = cr.scan.sectors
    uneven = dataclasses.replace(cr, scan=dataclasses.replace(cr.scan, sectors=(
        sectors[0], sectors[1], sectors[3])))
    with pytest.raises(ValueError, match='not evenly spaced'):
        scan_layout(uneven)


# ------------------------------------------------------------------------------------------
# the node, as a process

@pytest.fixture
def probe():
    p = Probe('detector_probe')
    yield p
    p.close()


def stamp_of(t: float) -> Time:
    return conv.to_time(t)


def stamp_key(stamp: Time) -> tuple[int, int]:
    return (stamp.sec, stamp.nanosec)


def answer(probe: Probe, topic: str, t: float, send, timeout: float = 10.0):
    """Publish a frame stamped ``t`` with ``send()`` (again every 0.25 s: the subscription
    is best effort) until the node's ``camera`` message stamped ``t`` arrives; that message."""
    want = stamp_of(t)
    found = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and not found:
        send()
        probe.spin_until(lambda: any(m.header.stamp == want for m in probe.msgs[topic]), 0.25)
        found = [m for m in probe.msgs[topic] if m.header.stamp == want]
    assert found, f'no {topic} message stamped {t}'
    return found[0]


@pytest.mark.ros
def test_the_node_reads_a_pinhole_robots_frames_and_camera_info(arena, scene, probe):
    """husky: its K (camera_info) replaces the 90 degree view; every frame's answer carries its
    stamp and the core's bearings and widths; mono16 frames are dropped with one error line,
    and the frames after them are read."""
    proc = start_node('clis_modules.detector_node', '-p', 'profile:=husky')
    try:
        probe.listen(JointState, 'camera', depth=100)
        probe.listen(Image, 'detector/overlay', depth=10)
        pub = probe.node.create_publisher(Image, '/image_raw', 10)
        info = probe.node.create_publisher(CameraInfo, '/camera_info', 10)
        assert probe.spin_until(lambda: pub.get_subscription_count() > 0
                                and info.get_subscription_count() > 0, 30), stop(proc)
        calibrated = detector('husky-k')
        camera = Pinhole.from_k(320, 240, K)
        frames = {}                                   # stamp -> the rgb frame sent
        info_msg = CameraInfo(width=320, height=240, k=K)

        def send(pose, t: float, encoding: str = 'rgb8'):
            rgb = frames[stamp_key(stamp_of(t))] = render(scene, camera, pose)
            msg = image_msg(rgb, stamp_of(t), 'front_camera')
            if encoding == 'mono16':
                msg.encoding, msg.step = 'mono16', 640
                msg.data = bytes(240 * 640)
            elif encoding == 'bgr8':
                msg.encoding = 'bgr8'
                msg.data = np.ascontiguousarray(rgb[..., ::-1]).tobytes()

            def go():
                info.publish(info_msg)
                pub.publish(msg)
            return rgb, go

        # frames until camera_info has arrived (the answer then has the K bearings)
        a = arena.start('A').pose
        pose = (a[0], a[1], a[2] + math.radians(20.0))      # the destination 20 deg right
        want = calibrated.frame(render(scene, camera, pose), 'rgb8')
        t = 1.0
        deadline = time.monotonic() + 20.0
        while True:
            t += 0.05
            got = answer(probe, 'camera', t, send(pose, t)[1])
            if np.array_equal(got.position, want.bearings, equal_nan=True):
                break
            assert time.monotonic() < deadline, 'camera_info never took effect'
        assert abs(wrap_angle(want.bearings[0] - truth(scene, pose, 0)['bearing'])) \
            <= camera.angle_per_pixel
        uncalibrated = detector('husky').frame(render(scene, camera, pose), 'rgb8')
        assert abs(uncalibrated.bearings[0] - want.bearings[0]) > 10 * camera.angle_per_pixel

        for k, p in enumerate([tuple(s.pose) for s in arena.starts] + POSES[:3]):
            t += 0.05
            rgb, go = send(p, t, 'bgr8' if k == 2 else 'rgb8')
            got = answer(probe, 'camera', t, go)
            want = calibrated.frame(rgb, 'rgb8')
            assert tuple(got.name) == NAMES and got.header.frame_id == 'base_link'
            np.testing.assert_array_equal(got.position, want.bearings)
            np.testing.assert_array_equal(got.effort, want.widths)
        assert sum(np.isfinite(m.position).sum() for m in probe.msgs['camera']) >= 10

        # unsupported frames (several: best effort may lose one): dropped, said once; the
        # next good frame is read
        bad = [t + 0.05 * i for i in range(1, 6)]
        for tb in bad:
            send(a, tb, 'mono16')[1]()
            probe.spin_for(0.05)
        t = bad[-1] + 0.05
        answer(probe, 'camera', t, send(a, t)[1])
        assert not {stamp_key(m.header.stamp) for m in probe.msgs['camera']} \
            & {stamp_key(stamp_of(tb)) for tb in bad}
        # the overlay (overlay: true by default): each frame with its boxes
        assert probe.spin_until(lambda: probe.msgs['detector/overlay'], 10)
        over = probe.msgs['detector/overlay'][-1]
        assert (over.encoding, over.width, over.height) == ('rgb8', 320, 240)
        assert over.header.frame_id == 'front_camera'
        rgb = frames[stamp_key(over.header.stamp)]
        drawn = calibrated.overlay(rgb, 'rgb8', calibrated.frame(rgb, 'rgb8'))
        assert np.any(drawn != rgb)
        np.testing.assert_array_equal(image_array(over), drawn)
    finally:
        out = stop(proc)
    said = [line for line in out.splitlines() if "'mono16'" in line]
    assert len(said) == 1, out
    assert '[ERROR]' in said[0] and all(e in said[0] for e in ("'rgb8'", "'bgr8'", "'rgba8'"))
    assert 'Traceback' not in out, out


@pytest.mark.ros
def test_the_node_in_a_namespace_reads_the_simulators_remapped_frames(arena, scene, probe):
    """cr (the omni-camera strip, no camera_info) in namespace /b, its /image_raw remapped to
    /front/image, fed by StandardTopics on a node in /front (image_raw remapped to image):
    /b/camera gives the pure core's bearings for each rendered pose; the overlay, off by
    parameter, comes once someone subscribes to it; the scan carries the IR readings."""
    proc = start_node('clis_modules.detector_node', '-p', 'profile:=cr', '-p', 'overlay:=false',
                      '-r', '__ns:=/b', '-r', '/image_raw:=/front/image')
    sim = rclpy.create_node('sim', namespace='/front', context=probe.context,
                            cli_args=['--ros-args', '-r', 'image_raw:=image'])
    probe.executor.add_node(sim)
    try:
        topics = StandardTopics(sim, arena, 'cr', sensors=load_sim_params().sensors)
        assert topics.pub_info is None, 'a panoramic strip has no camera_info'
        assert topics.pub_image.topic_name == '/front/image'
        assert topics.messages(0.0, (0.0, 0.5, 0.0), np.zeros(7)) == [], 'built on demand'
        probe.listen(JointState, '/b/camera', depth=100)
        probe.listen(LaserScan, '/front/scan', depth=100)
        assert probe.spin_until(lambda: topics.pub_image.get_subscription_count() > 0
                                and topics.pub_scan.get_subscription_count() > 0, 30), stop(proc)
        core = detector('cr')
        t = 0.0
        for pose in [tuple(s.pose) for s in arena.starts] + POSES:
            t += 0.05
            ir = np.linspace(0.05, 0.5, 7) * (1.0 + t)
            got = answer(probe, '/b/camera', t,
                         lambda t=t, pose=pose, ir=ir: topics.publish(t, pose, ir))
            want = core.frame(render(topics.scene, core.nominal, pose), 'rgb8')
            assert tuple(got.name) == NAMES
            np.testing.assert_array_equal(got.position, want.bearings)
            np.testing.assert_array_equal(got.effort, want.widths)
            def scans(t=t):
                return [m for m in probe.msgs['/front/scan'] if m.header.stamp == stamp_of(t)]
            assert probe.spin_until(scans, 10), f'no scan stamped {t}'
            assert np.allclose(scans()[0].ranges, ir, atol=1e-6)
        assert sum(np.isfinite(m.position).sum() for m in probe.msgs['/b/camera']) >= 20
        probe.listen(Image, '/b/detector/overlay', depth=10)
        t += 0.05
        pose = POSES[0]
        deadline = time.monotonic() + 10.0
        while not probe.msgs['/b/detector/overlay'] and time.monotonic() < deadline:
            topics.publish(t, pose, ir)
            probe.spin_until(lambda: probe.msgs['/b/detector/overlay'], 0.5)
        over = probe.msgs['/b/detector/overlay']
        assert over and (over[0].width, over[0].height) == (360, 40)
        frame = render(topics.scene, core.nominal, pose)
        np.testing.assert_array_equal(
            image_array(over[0]), core.overlay(frame, 'rgb8', core.frame(frame, 'rgb8')))
    finally:
        probe.executor.remove_node(sim)
        sim.destroy_node()
        out = stop(proc)
    assert '[ERROR]' not in out and 'Traceback' not in out, out
