"""Robot profiles (cr_sim.core.profile, config/robots): every shipped profile loads, the cr
profile is the simulator's robot, and a bad value is reported with its key and range."""

from __future__ import annotations

import math
from pathlib import Path
import shutil

from clis_base.params import ConfigError, as_dict, config_dir, load_yaml
from clis_modules.core.blobs import NAMED_RANGES, ColourRange
from cr_sim.core import profile as prof
from cr_sim.core.arena import load_arena
from cr_sim.core.camera import Panoramic, Pinhole
from cr_sim.core.profile import ColourSpec, load_profile
from cr_sim.core.render import DESTINATION_COLOUR, RenderParams
from cr_sim.core.robot import load_robot_params
from cr_sim.core.sim import load_sim_params
import numpy as np
import pytest
import yaml

SHIPPED = ('cr', 'husky', 'turtlebot4')


def variant(tmp_path: Path, name: str, dotted: str, value) -> Path:
    """A copy of profile ``name`` with ``dotted`` (``scan.sectors.2.width_deg``) set to
    ``value``, as ``tmp_path/NAME.yaml`` (the profile keeps its name)."""
    data = load_yaml(config_dir() / 'robots' / f'{name}.yaml')
    *path, last = dotted.split('.')
    node = data
    for key in path:
        node = node[int(key)] if isinstance(node, list) else node[key]
    node[int(last) if isinstance(node, list) else last] = value
    out = tmp_path / f'{name}.yaml'
    out.write_text(yaml.safe_dump(data, sort_keys=False), encoding='utf-8')
    return out


def test_profile_names_lists_the_shipped_profiles():
    assert prof.PROFILE_NAMES() == SHIPPED


@pytest.mark.parametrize('name', SHIPPED)
def test_every_profile_loads_and_reads_the_scan_in_the_crs_ir_directions(name):
    p = load_profile(name)
    assert p == load_profile(config_dir() / 'robots' / f'{name}.yaml'), 'by name = by path'
    assert p.description
    # the modules read the IR beams: every robot's sectors are the simulator's directions
    assert p.scan.angles_deg == tuple(load_sim_params().sensors.ir_angles_deg)
    model = p.camera.camera_model()
    assert isinstance(model, Panoramic if p.camera.model == 'panoramic' else Pinhole)
    assert math.degrees(model.hfov) == pytest.approx(p.camera.hfov_deg)
    middle = 0.5 * (model.width - 1) if p.camera.model == 'pinhole' else 0.5 * model.width
    assert model.column_of_bearing(0.0) == pytest.approx(middle), 'the heading in the middle'


def test_the_cr_profile_is_the_simulators_robot():
    p = load_profile('cr')
    sim, body, arena = load_sim_params(), load_robot_params(), load_arena()
    assert p.scan.angles_deg == tuple(sim.sensors.ir_angles_deg)
    assert [s.width_deg for s in p.scan.sectors] == [0.0] * len(sim.sensors.ir_angles_deg)
    assert p.scan.range_max == sim.sensors.ir_range
    assert p.scan.from_surface and p.scan.yaw_deg == 0.0
    assert (p.body.radius, p.body.wheel_base, p.body.v_wheel_max) == \
        (body.radius, body.wheel_base, body.v_wheel_max)
    assert p.body.v_max == body.v_wheel_max
    assert p.body.omega_max == pytest.approx(2.0 * body.v_wheel_max / body.wheel_base)
    assert p.episode.time_limit == sim.episode.time_limit
    assert p.episode.wander_time == sim.episode.wander_time
    assert p.colours.destination == ColourSpec(DESTINATION_COLOUR, None)
    assert p.colours.landmarks == tuple((m.name, ColourSpec(m.colour, None))
                                        for m in arena.landmarks)
    assert p.arena.path() == config_dir() / 'arena.yaml'
    assert p.arena.scale(arena.size) == 1.0
    # reached: the destination's cylinder seen from the goal radius, to the strip's 1 deg
    goal = 2.0 * math.degrees(math.asin(RenderParams().target_radius
                                        / arena.destination.goal_radius))
    assert p.episode.reached.rule == 'size'
    assert goal - 1.0 <= p.episode.reached.width_deg <= goal
    # the omni-camera's strip: the heading at the middle column, the full turn
    model = p.camera.camera_model()
    assert model.bearing_of_column(model.width / 2) == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize('name', SHIPPED)
def test_each_sector_range_is_the_crs_ir_range_at_the_arenas_scale(name):
    p = load_profile(name)
    scale = p.arena.scale(load_arena(p.arena.path()).size)
    assert p.scan.range_max == pytest.approx(load_sim_params().sensors.ir_range * scale,
                                             abs=0.005)


def test_the_turtlebot4_profile_is_the_jazzy_robots():
    p = load_profile('turtlebot4')
    assert p.topics.cmd_vel_type == 'TwistStamped'
    assert (p.topics.image, p.topics.camera_info) == \
        ('oakd/rgb/preview/image_raw', 'oakd/rgb/preview/camera_info')
    assert p.scan.yaw_deg == 90.0 and not p.scan.from_surface, 'the RPLIDAR turned by pi/2'
    assert p.body.v_max <= p.body.v_wheel_max


BAD = [
    ('husky', 'camera.hfov_deg', 400.0,
     'camera.hfov_deg = 400.0 is out of range: must be in [1, 360]'),
    ('husky', 'camera.hfov_deg', 200.0,
     'camera.hfov_deg = 200.0 is out of range for a pinhole camera: must be below 180'),
    ('cr', 'camera.hfov_deg', 180.0, 'camera.hfov_deg = 180.0 must be 360 for a panoramic'),
    ('turtlebot4', 'scan.sectors.2.width_deg', -5.0,
     'scan.sectors[2].width_deg = -5.0 is out of range: must be in [0.0, 360.0]'),
    ('turtlebot4', 'topics.cmd_vel_type', 'Twisted',
     "topics.cmd_vel_type = 'Twisted' is not allowed: must be one of 'auto', 'Twist', "
     "'TwistStamped'"),
    ('turtlebot4', 'topics.scan', '2scan', "topics.scan = '2scan' is not a topic name"),
    ('cr', 'body.radius', 0.0, 'body.radius = 0.0 is out of range: must be in [0.01, 2.0]'),
    ('cr', 'body.v_max', 2.0, 'body.v_max = 2.0 exceeds body.v_wheel_max = 1.3'),
    ('cr', 'body.wheels', 2,
     'unknown key body.wheels; allowed keys: omega_max, radius, v_max, v_wheel_max'),
    ('cr', 'colours.destination', 'pink',
     "colours.destination = 'pink' is not a colour name: must be one of red, orange"),
    ('cr', 'colours.landmarks.L1', {'hue_lo': 400.0, 'hue_hi': 20.0, 'sat_lo': 0.5,
                                    'sat_hi': 1.0, 'val_lo': 0.2, 'val_hi': 1.0},
     'colours.landmarks.L1.hue_lo = 400.0 is out of range: must be in [0.0, 360.0]'),
    ('cr', 'colours.landmarks.L1', {'hue_lo': 10.0, 'hue_hi': 20.0, 'sat_lo': 0.9,
                                    'sat_hi': 0.5, 'val_lo': 0.2, 'val_hi': 1.0},
     'colours.landmarks.L1: sat_lo = 0.9 exceeds sat_hi = 0.5'),
    ('cr', 'episode.collision_range', 0.5,
     'episode.collision_range = 0.5 is not below scan.range_max = 0.5'),
    ('cr', 'episode.reached.width_deg', 0.0,
     "episode.reached: rule 'size' needs width_deg or area_px above 0"),
    ('husky', 'episode.collision_sectors.0.angle_deg', 200.0,
     'episode.collision_sectors[0].angle_deg = 200.0 is out of range: must be in '
     '[-180.0, 180.0]'),
    ('cr', 'episode.stale_timeout', 0.0,
     'episode.stale_timeout = 0.0 is out of range: must be in [0.01, 10.0]'),
    ('husky', 'arena.size', 3.0,
     'arena.size = 3.0: the layout scaled by 1 has no room for body.radius = 0.6'),
]


@pytest.mark.parametrize('name, key, value, message', BAD, ids=[f'{b[0]}:{b[1]}' for b in BAD])
def test_a_bad_value_names_the_profile_the_key_and_its_range(tmp_path, name, key, value,
                                                             message):
    path = variant(tmp_path, name, key, value)
    with pytest.raises(ConfigError) as err:
        load_profile(path)
    text = str(err.value)
    assert text.startswith(f'profile {name}: {message}'), text
    assert text.endswith(f'({path})')


def test_the_colours_must_name_the_arenas_landmarks(tmp_path):
    data = load_yaml(config_dir() / 'robots' / 'cr.yaml')
    del data['colours']['landmarks']['L4']
    path = tmp_path / 'cr.yaml'
    path.write_text(yaml.safe_dump(data), encoding='utf-8')
    with pytest.raises(ConfigError, match=r'colours.landmarks names L1, L2, L3: must be the '
                       r'landmarks of .*arena.yaml: L1, L2, L3, L4'):
        load_profile(path)


def test_an_explicit_colour_is_the_blob_detectors_hsv_range(tmp_path):
    box = {'hue_lo': 350.0, 'hue_hi': 10.0, 'sat_lo': 0.4, 'sat_hi': 1.0, 'val_lo': 0.3,
           'val_hi': 0.9}
    spec = load_profile(variant(tmp_path, 'cr', 'colours.landmarks.L1', box)).colours.of('L1')
    assert spec.name == '' and ColourRange(**as_dict(spec.hsv)) == ColourRange(
        350.0, 10.0, 0.4, 1.0, 0.3, 0.9)


def test_the_colour_names_are_those_the_blob_detector_has_a_range_for():
    assert set(prof.COLOUR_NAMES) == set(NAMED_RANGES)


def test_relative_topics_go_under_the_namespace(tmp_path):
    topics = load_profile(variant(tmp_path, 'turtlebot4', 'topics.namespace', 'robot1')).topics
    assert topics.resolved('image') == '/robot1/oakd/rgb/preview/image_raw'
    assert topics.resolved('cmd_vel') == '/robot1/cmd_vel'
    assert load_profile('turtlebot4').topics.resolved('odom') == 'odom'
    assert load_profile('cr').topics.resolved('camera_info') == ''


def test_an_unknown_profile_name_lists_the_known_ones(tmp_path):
    with pytest.raises(ConfigError, match=r"unknown robot profile 'huskyy': known profiles: "
                       r'cr, husky, turtlebot4 \('):
        load_profile('huskyy')
    with pytest.raises(ConfigError, match='no such file'):
        load_profile(tmp_path / 'nothing.yaml')


def test_profiles_are_found_through_the_config_folder(tmp_path, monkeypatch):
    conf = tmp_path / 'config'
    shutil.copytree(config_dir() / 'robots', conf / 'robots')
    shutil.copy(config_dir() / 'arena.yaml', conf / 'arena.yaml')
    data = load_yaml(conf / 'robots' / 'cr.yaml')
    data['description'] = 'a second CR'
    (conf / 'robots' / 'cr2.yaml').write_text(yaml.safe_dump(data), encoding='utf-8')
    monkeypatch.setenv('CLIS_CONFIG_DIR', str(conf))
    assert prof.PROFILE_NAMES() == ('cr', 'cr2', 'husky', 'turtlebot4')
    assert load_profile('cr2').description == 'a second CR'
    shutil.rmtree(conf / 'robots')
    assert prof.PROFILE_NAMES() == ()
    with pytest.raises(ConfigError, match="unknown robot profile 'cr': known profiles: none"):
        load_profile('cr')


@pytest.mark.parametrize('heading', [0.0, 1.0, 2.5])
def test_the_cr_profiles_reached_rule_holds_where_the_simulators_does(heading):
    """Through the standard path the destination is reached when its blob looks at least
    ``episode.reached.width_deg`` wide: on the rendered strip that must happen where the
    simulator's rule does (the robot's centre within the goal radius), and the destination
    must stay in the image nearer still (a marker lower than the camera left the strip's rows
    there, and no episode was ever reached). The robot walks in 5 mm steps toward the
    destination, from any side, at any heading."""
    from clis_modules.detector_node import detector_of
    from cr_sim.core.render import Scene, render
    p = load_profile('cr')
    arena = load_arena()
    sensors = load_sim_params().sensors
    scene = Scene.from_arena(arena, RenderParams(camera_range=sensors.camera_range,
                                                 destination_range=sensors.destination_range))
    camera, detector = p.camera.camera_model(), detector_of(p)
    dest, goal = arena.destination, arena.destination.goal_radius
    r = RenderParams().target_radius
    side = heading + 0.7
    widths = []
    for d in np.arange(0.4, r + 0.01, -0.005):
        pose = np.array([dest.x - d * math.cos(side), dest.y - d * math.sin(side), heading])
        found = detector.frame(render(scene, camera, pose), 'rgb8')
        widths.append((d, math.degrees(found.widths[0])))
    assert all(math.isfinite(w) for _, w in widths), 'the destination left the image'
    first = next(d for d, w in widths if w >= p.episode.reached.width_deg)
    assert goal - 0.005 <= first <= goal + 0.0075, (first, widths)
    assert all(w >= p.episode.reached.width_deg for d, w in widths if d <= first)
