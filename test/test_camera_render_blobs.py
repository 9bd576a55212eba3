"""Camera models, the rendered camera and the colour-blob detector (cr_sim.core.camera,
cr_sim.core.render, clis_modules.core.blobs): the detector's bearings in rendered frames of the
default arena are the true bearings within one pixel's angle, hidden targets are not seen."""

from __future__ import annotations

import dataclasses
import math

from clis_modules.core.blobs import (
    NAMED_RANGES,
    BlobParams,
    ColourRange,
    bearings,
    candidates,
    detect,
    hsv,
    target_masks,
)
from cr_sim.core.arena import load_arena
from cr_sim.core.camera import Panoramic, Pinhole
from cr_sim.core.geometry import wrap_angle
from cr_sim.core.render import DESTINATION_COLOUR, RenderParams, Scene, render
import numpy as np
import pytest
from render_truth import truth as _truth

R = 0.11                               # robot radius of config/robot.yaml
PAN = Panoramic(360, 40)               # the CR's omni-camera, unrolled
PIN = Pinhole.from_fov(160, 120, math.radians(60.0))
CAMERAS = {
    'panoramic': PAN,
    'panoramic-mirrored': Panoramic(300, 30, bearing0=-2.0, clockwise=False),
    'pinhole': PIN,
    'pinhole-k-left': Pinhole.from_k(320, 240, [200.0, 0.0, 150.0, 0.0, 210.0, 110.0, 0, 0, 1],
                                     yaw=0.8),
}
POSES = [(0.5, 0.5, 0.3), (-0.9, -1.1, 2.0), (1.0, -0.1, -2.5), (-0.3, 1.2, -1.2),
         (0.2, -0.5, 0.0), (-1.2, 0.9, -0.6)]


@pytest.fixture(scope='module')
def arena():
    return load_arena()


def _params(arena) -> BlobParams:
    return BlobParams({'destination': NAMED_RANGES[DESTINATION_COLOUR],
                       **{lm.name: NAMED_RANGES[lm.colour] for lm in arena.landmarks}})


def _poses(arena) -> list[tuple[float, float, float]]:
    poses = [tuple(s.pose) for s in arena.starts] + POSES
    assert all(arena.gap(x, y, R) > 0.0 for x, y, _ in poses)
    return poses



def _in_view(camera, b: float, alpha: float) -> str:
    """'in' when the whole silhouette is in the image, 'out' when none of it, else 'edge'."""
    if isinstance(camera, Panoramic):
        return 'in'
    edges = np.isfinite(camera.column_of_bearing(np.array((b - alpha, b + alpha))))
    return 'in' if edges.all() else ('out' if not edges.any() else 'edge')


# ------------------------------------------------------------------------------------------
# camera models

def test_pinhole_round_trips_and_field_of_view_edges():
    for cam in (PIN, Pinhole.from_fov(101, 50, 2.5, yaw=math.pi - 0.2)):
        half = 0.5 * (cam.hfov)
        u = np.linspace(-0.5, cam.width - 0.5, 1001)
        assert np.allclose(cam.column_of_bearing(cam.bearing_of_column(u)), u, atol=1e-9)
        b = cam.yaw + np.linspace(-half, half, 1001)[1:-1]
        back = cam.bearing_of_column(cam.column_of_bearing(b))
        assert np.allclose([wrap_angle(v) for v in back - b], 0.0, atol=1e-12)
        assert np.all((back > -math.pi) & (back <= math.pi))
        assert wrap_angle(cam.bearing_of_column(-0.5) - (cam.yaw + half)) == pytest.approx(0.0)
        assert wrap_angle(cam.bearing_of_column(cam.width - 0.5) - (cam.yaw - half)) \
            == pytest.approx(0.0, abs=1e-12)
        assert cam.column_of_bearing(cam.yaw + half - 1e-9) == pytest.approx(-0.5, abs=1e-5)
        assert math.isnan(cam.column_of_bearing(cam.yaw + half + 1e-6))
        assert math.isnan(cam.column_of_bearing(cam.yaw - half - 1e-6))
        assert math.isnan(cam.column_of_bearing(cam.yaw + math.pi))
        per_column = -np.diff(cam.bearing_of_column(np.arange(cam.width + 1) - 0.5))
        per_column = np.array([wrap_angle(v) for v in per_column])
        assert per_column.max() <= cam.angle_per_pixel + 1e-15
        assert per_column.max() == pytest.approx(cam.angle_per_pixel, rel=1e-3)
    assert PIN.hfov == pytest.approx(math.radians(60.0))
    assert PIN.bearing_of_column(0) > 0.0 > PIN.bearing_of_column(159)   # left > 0 > right


def test_pinhole_from_camera_info_k():
    k = [300.0, 0.0, 160.5, 0.0, 310.0, 119.5, 0.0, 0.0, 1.0]
    cam = Pinhole.from_k(320, 240, np.reshape(k, (3, 3)), yaw=-0.5)
    assert (cam.fx, cam.cx, cam.fy, cam.cy, cam.yaw) == (300.0, 160.5, 310.0, 119.5, -0.5)
    assert cam.bearing_of_column(160.5) == -0.5
    assert cam.bearing_of_column(160.5 + 300.0) == pytest.approx(-0.5 - math.pi / 4)
    with pytest.raises(ValueError, match='k has 4 numbers'):
        Pinhole.from_k(320, 240, [1, 2, 3, 4])


def test_panoramic_round_trips_and_seam():
    cam = PAN
    assert cam.angle_per_pixel == pytest.approx(math.radians(1.0))
    assert cam.bearing_of_column(0) == pytest.approx(math.pi)           # behind
    assert cam.bearing_of_column(90) == pytest.approx(math.pi / 2)      # left
    assert cam.bearing_of_column(180) == pytest.approx(0.0)             # ahead: the middle
    assert cam.bearing_of_column(270) == pytest.approx(-math.pi / 2)    # right
    mirrored = Panoramic(360, 40, clockwise=False)
    assert mirrored.bearing_of_column(90) == pytest.approx(-math.pi / 2)
    for c in (cam, mirrored, CAMERAS['panoramic-mirrored']):
        u = np.linspace(-0.5, c.width - 0.5, 2001)[:-1]
        got = c.column_of_bearing(c.bearing_of_column(u))
        assert np.all((got >= -0.5) & (got < c.width - 0.5))
        assert np.allclose((got - u + c.width / 2) % c.width - c.width / 2, 0.0, atol=1e-9)
        b = np.linspace(-3 * math.pi, 3 * math.pi, 997)
        back = c.bearing_of_column(c.column_of_bearing(b))
        assert np.allclose([wrap_angle(v) for v in back - b], 0.0, atol=1e-12)
        assert np.all((back > -math.pi) & (back <= math.pi))
    assert math.isnan(cam.column_of_bearing(math.nan))


@pytest.mark.parametrize('make, field, allowed', [
    (lambda: Pinhole.from_fov(160, 120, math.pi), 'hfov', '(0, pi)'),
    (lambda: Pinhole.from_fov(0, 120, 1.0), 'width', '[1, 100000]'),
    (lambda: Pinhole(160, 120, -1.0, 80.0, 100.0, 60.0), 'fx', '(0, inf)'),
    (lambda: Pinhole(160, 120, 100.0, 80.0, 100.0, math.nan), 'cy', '(-inf, inf)'),
    (lambda: Pinhole.from_fov(160, 120, 1.0, yaw=4.0), 'yaw', '[-pi, pi]'),
    (lambda: Panoramic(360, 0), 'height', '[1, 100000]'),
    (lambda: Panoramic(360.5, 40), 'width', '[1, 100000]'),
    (lambda: Panoramic(360, 40, bearing0=-4.0), 'bearing0', '[-pi, pi]'),
    (lambda: RenderParams(target_radius=0.0), 'target_radius', '(0, 1]'),
    (lambda: RenderParams(camera_range=0.0), 'camera_range', '[0.1, 100]'),
    (lambda: RenderParams(camera_height=0.05), 'camera_height', '(short_height, tall_height)'),
    (lambda: ColourRange(400.0, 10.0), 'hue_lo', '[0, 360]'),
    (lambda: ColourRange(10.0, 20.0, sat_lo=0.6, sat_hi=0.5), 'sat_hi', '[0.6, 1]'),
    (lambda: BlobParams({'a': ColourRange(0.0, 10.0)}, min_area=0), 'min_area', '[1, 1e+09]'),
])
def test_bad_parameters_name_the_field_and_its_range(make, field, allowed):
    with pytest.raises(ValueError) as info:
        make()
    assert str(info.value).startswith(f'{field} = ') and allowed in str(info.value)


# ------------------------------------------------------------------------------------------
# rendered frames against the geometry

@pytest.mark.parametrize('name', sorted(CAMERAS))
@pytest.mark.parametrize('ranges', [(5.0, 0.0), (1.6, 1.0)])
def test_detected_bearings_are_the_true_ones_within_a_pixel(arena, name, ranges):
    """Every target in view, clear of tall obstacles, in range and not overlapping another
    target's silhouette is seen at its true bearing within one pixel's angle; every target
    wholly behind a tall obstacle, out of range or out of view is not seen."""
    camera = CAMERAS[name]
    scene = Scene.from_arena(arena, RenderParams(camera_range=ranges[0],
                                                 destination_range=ranges[1]))
    params = _params(arena)
    checked = {'seen': 0, 'not seen': 0}
    for pose in _poses(arena):
        blobs = detect(render(scene, camera, pose), 'rgb8', camera, params)
        truth = [_truth(scene, pose, k) for k in range(len(scene.names))]
        for k, (target, tr) in enumerate(zip(scene.names, truth)):
            where = f'{target} from {pose}: {tr}, {blobs[target]}'
            view = _in_view(camera, tr['bearing'], tr['alpha'])
            in_range = tr['dist'] <= scene.ranges[k]
            crowded = any(abs(wrap_angle(o['bearing'] - tr['bearing']))
                          < o['alpha'] + tr['alpha'] + camera.angle_per_pixel
                          for j, o in enumerate(truth) if j != k)
            if in_range and tr['clear'] and view == 'in' and not crowded:
                assert blobs[target].seen, where
                err = wrap_angle(blobs[target].bearing - tr['bearing'])
                assert abs(err) <= camera.angle_per_pixel, where
                assert blobs[target].width == pytest.approx(2 * tr['alpha'],
                                                            abs=2 * camera.angle_per_pixel)
                checked['seen'] += 1
            elif not in_range or tr['hidden'] or view == 'out':
                assert not blobs[target].seen and math.isnan(blobs[target].bearing), where
                checked['not seen'] += 1
    assert checked['seen'] >= (8 if ranges[0] > 2.0 else 1) and checked['not seen'] >= 2, checked


@pytest.mark.parametrize('name', ['panoramic', 'pinhole'])
def test_start_e_hides_the_destination_behind_the_tall_obstacle(arena, name):
    """From start E, T1 stands between the robot and the destination (docs/results.md,
    Protocol); without the tall obstacles the destination is seen at its true bearing."""
    camera, pose = CAMERAS[name], arena.start('E').pose
    params = _params(arena)
    truth = _truth(Scene.from_arena(arena), pose, 0)
    assert truth['hidden'] and abs(truth['bearing']) < 0.1
    hidden = detect(render(Scene.from_arena(arena), camera, pose), 'rgb8', camera, params)
    assert not hidden['destination'].seen and hidden['destination'].area == 0
    bare = Scene.from_arena(dataclasses.replace(arena, tall_obstacles=()))
    shown = detect(render(bare, camera, pose), 'rgb8', camera, params)
    assert shown['destination'].seen
    assert abs(wrap_angle(shown['destination'].bearing - truth['bearing'])) \
        <= camera.angle_per_pixel


def test_short_obstacles_hide_nothing(arena):
    """From start D, short obstacle S1 stands across the line to the destination: it is
    drawn (below the horizon) and the destination is seen over it."""
    pose = arena.start('D').pose
    scene = Scene.from_arena(arena)
    img = render(scene, PIN, pose)
    blob = detect(img, 'rgb8', PIN, _params(arena))['destination']
    assert blob.seen and abs(blob.bearing) <= PIN.angle_per_pixel
    no_short = render(Scene.from_arena(dataclasses.replace(arena, short_obstacles=())), PIN,
                      pose)
    differs = np.any(img != no_short, axis=2)
    assert differs.any() and not differs[:int(PIN.cy) + 1].any()    # S1: below the horizon


def test_a_target_outside_the_pinholes_view_is_not_seen(arena):
    """The destination straight ahead from A is seen; turned 40 degrees (more than half
    the 60 degree field of view plus its half-width) or 180 degrees, it is not."""
    x, y, th = arena.start('A').pose
    scene, params = Scene.from_arena(arena), _params(arena)
    for turn, seen in ((0.0, True), (math.radians(25.0), True), (math.radians(40.0), False),
                       (math.radians(-40.0), False), (math.pi, False)):
        blob = detect(render(scene, PIN, (x, y, th + turn)), 'rgb8', PIN, params)
        assert blob['destination'].seen == seen, turn
        if seen:
            assert abs(wrap_angle(blob['destination'].bearing + turn)) <= PIN.angle_per_pixel


def test_rendering_is_deterministic_and_of_the_cameras_shape(arena):
    scene = Scene.from_arena(arena)
    for camera in CAMERAS.values():
        a = render(scene, camera, (0.3, 0.2, 1.0))
        assert a.shape == (camera.height, camera.width, 3) and a.dtype == np.uint8
        assert np.array_equal(a, render(scene, camera, (0.3, 0.2, 1.0)))


# ------------------------------------------------------------------------------------------
# the detector

@pytest.mark.parametrize('encoding', ['mono8', 'RGB8', 'bgra8', ''])
def test_a_bad_encoding_raises_one_line(arena, encoding):
    img = render(Scene.from_arena(arena), PAN, arena.start('A').pose)
    with pytest.raises(ValueError) as info:
        detect(img, encoding, PAN, _params(arena))
    msg = str(info.value)
    assert '\n' not in msg and repr(encoding) in msg
    assert all(e in msg for e in ("'rgb8'", "'bgr8'", "'rgba8'"))


def test_bgr8_and_rgba8_give_the_bearings_of_rgb8(arena):
    scene, params = Scene.from_arena(arena), _params(arena)
    names = scene.names
    for camera in (PAN, PIN):
        for pose in _poses(arena)[:6]:
            rgb = render(scene, camera, pose)
            rgba = np.concatenate([rgb, np.full(rgb.shape[:2] + (1,), 255, np.uint8)], axis=2)
            want = detect(rgb, 'rgb8', camera, params)
            assert np.isfinite(bearings(want, names)).sum() >= 1
            for img, enc in ((np.ascontiguousarray(rgb[..., ::-1]), 'bgr8'), (rgba, 'rgba8')):
                got = detect(img, enc, camera, params)
                np.testing.assert_array_equal(bearings(got, names), bearings(want, names))
                assert [b.area for b in got.values()] == [b.area for b in want.values()]
    with pytest.raises(ValueError, match=r'a rgba8 image is uint8 of shape \(H, W, 4\)'):
        detect(rgb, 'rgba8', PIN, params)


def _strip(spans: list[tuple[int, int]], rows: slice = slice(10, 21)) -> np.ndarray:
    """A grey 40 x 360 strip with red columns ``[lo, hi)`` of each span."""
    img = np.full((40, 360, 3), 128, np.uint8)
    for lo, hi in spans:
        img[rows, lo:hi] = (220, 40, 40)
    return img


def test_a_blob_across_the_panoramic_seam_gets_the_right_bearing():
    """Columns 355..359 and 0..2 are one blob of 8 columns (centroid 358.5, behind the robot,
    half a degree left of the seam), larger than the 6-column blob at column 100."""
    params = BlobParams({'L1': NAMED_RANGES['red']})
    blob = detect(_strip([(355, 360), (0, 3), (100, 106)]), 'rgb8', PAN, params)['L1']
    assert blob.seen and blob.area == 8 * 11
    assert blob.column == pytest.approx(358.5)
    assert blob.bearing == pytest.approx(PAN.bearing_of_column(358.5), abs=1e-12)
    assert blob.width == pytest.approx(8 * PAN.angle_per_pixel)
    # the same blob away from the seam
    moved = detect(_strip([(200, 208), (100, 106)]), 'rgb8', PAN, params)['L1']
    assert moved.area == blob.area and moved.column == pytest.approx(203.5)


def test_a_rendered_target_behind_the_robot_straddles_the_seam(arena):
    """The destination straight behind the robot: its pixels lie in the first and the last
    columns of the strip, and its bearing is pi within one pixel's angle."""
    img = render(Scene.from_arena(arena), PAN, (0.0, 0.5, math.pi / 2))
    mask = NAMED_RANGES[DESTINATION_COLOUR].mask(*hsv(img, 'rgb8'))
    assert mask[:, 0].any() and mask[:, -1].any()
    blob = detect(img, 'rgb8', PAN, _params(arena))['destination']
    assert blob.seen and abs(wrap_angle(blob.bearing - math.pi)) <= PAN.angle_per_pixel
    assert blob.area == mask.sum()


def test_the_largest_blob_counts_and_a_small_one_is_not_seen():
    cam = Pinhole.from_fov(360, 40, 2.0)
    two = _strip([(50, 53), (300, 310)])                  # 3 and 10 columns
    blob = detect(two, 'rgb8', cam, BlobParams({'L1': NAMED_RANGES['red']}))['L1']
    assert blob.column == pytest.approx(304.5) and blob.area == 110
    tiny = _strip([(50, 53)], rows=slice(10, 11))         # 3 pixels
    for min_area, seen in ((3, True), (4, False)):
        got = detect(tiny, 'rgb8', cam, BlobParams({'L1': NAMED_RANGES['red']}, min_area))
        assert got['L1'].seen == seen and got['L1'].area == 3
        assert math.isnan(got['L1'].bearing) != seen
    none = detect(_strip([]), 'rgb8', cam, BlobParams({'L1': NAMED_RANGES['red']}))['L1']
    assert (none.seen, none.area) == (False, 0) and math.isnan(none.width)


@pytest.mark.parametrize('encoding', ['rgb8', 'bgr8', 'rgba8'])
def test_the_masks_are_hsvs_on_every_pixel_the_prefilter_keeps_no_match_out(encoding):
    # target_masks computes hsv only on the candidates: its masks must be those of hsv on the
    # whole image, pixel for pixel, for colours at every range's bounds (where rounding
    # decides) and for random ones.
    rng = np.random.default_rng(7)
    ranges = [*NAMED_RANGES.values(), ColourRange(0.0, 360.0, 0.0, 1.0, 0.0, 1.0),
              ColourRange(100.0, 140.0, 0.97, 1.0, 0.9, 1.0)]
    near = []
    for r in ranges:
        for v_lo in (r.val_lo, r.val_hi):
            for s_lo in (r.sat_lo, r.sat_hi):
                big = np.clip(np.round(v_lo * 255) + np.arange(-2, 3), 0, 255)
                for m in big:
                    low = np.clip(np.round(m * (1.0 - s_lo)) + np.arange(-2, 3), 0, m)
                    near += [(m, lo, mid) for lo in low for mid in (lo, m, (m + lo) // 2)]
    near = np.array(near, dtype=np.uint8)
    pixels = np.concatenate([near, near[:, ::-1], near[:, [1, 2, 0]],
                             rng.integers(0, 256, (20000, 3), dtype=np.uint8)])
    image = pixels[:len(pixels) // 100 * 100].reshape(100, -1, 3)
    if encoding == 'rgba8':
        image = np.concatenate([image, rng.integers(0, 256, image.shape[:2] + (1,),
                                                    dtype=np.uint8)], axis=2)
    for targets in ([('all', ranges[-2])], list(zip('abcdefgh', ranges[:8])),
                    [('sat', ranges[-1])]):
        params = BlobParams(tuple(targets))
        h, s, v = hsv(image, encoding)
        masks = target_masks(image, encoding, params)
        for (name, r), mask in zip(targets, masks):
            expected = r.mask(h, s, v)
            assert np.array_equal(mask, expected), name
            assert expected.any()
    assert candidates(image, ranges[:8]).mean() < 1.0         # it does drop pixels
