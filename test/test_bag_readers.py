"""Bags as rosbag2 writes them: schema texts byte for byte against golden texts, and
a recorded bag opened by Foxglove's TypeScript MCAP stack, rosbags and mcap-ros2-support.

The golden texts (test/golden/ros2msg/) are made by test/golden/make_schemas.py from the
installed ``.msg`` files, following rosbag2_cpp's ``LocalMessageDefinitionSource`` step by
step, not through the project's writer. The Foxglove reader (test/foxglove_reader/) is the npm
packages the Foxglove app reads MCAP with (``@mcap/core`` 2.2.2, ``@foxglove/rosmsg`` 5.0.5,
``@foxglove/rosmsg2-serialization`` 3.1.0), pinned by its package-lock.json; ``make setup``
installs it, and this test does when it is missing. A reader that cannot be set up fails the
test.
"""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path
import shutil
import subprocess
import sys

from clis_app.bags.mcap import SEPARATOR, BagReader, BagWriter, bag_topics, definition
import pytest

REPO = Path(__file__).resolve().parent.parent
GOLDEN = REPO / 'test' / 'golden'
FOXGLOVE = REPO / 'test' / 'foxglove_reader'
_spec = importlib.util.spec_from_file_location('make_schemas', GOLDEN / 'make_schemas.py')
make_schemas = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(make_schemas)
golden_path, TYPES = make_schemas.golden_path, make_schemas.TYPES

# the types a `clis run --record` bag holds (the async condition: every module)
RECORDED = {'diagnostic_msgs/msg/DiagnosticArray', 'geometry_msgs/msg/TwistStamped',
            'geometry_msgs/msg/Vector3Stamped', 'nav_msgs/msg/OccupancyGrid',
            'nav_msgs/msg/Odometry', 'rosgraph_msgs/msg/Clock', 'sensor_msgs/msg/JointState',
            'sensor_msgs/msg/LaserScan', 'visualization_msgs/msg/MarkerArray'}


# ---------------------------------------------------------------------------- schema texts

def test_golden_texts_are_those_of_the_installed_msg_files():
    out = subprocess.run([sys.executable, str(GOLDEN / 'make_schemas.py'), '--check'],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stdout + out.stderr


@pytest.mark.parametrize('msg_type', TYPES)
def test_schema_text_is_rosbag2s_byte_for_byte(msg_type):
    golden = golden_path(msg_type).read_bytes()
    encoding, data = definition(msg_type)
    assert encoding == 'ros2msg'
    assert data == golden, f'{msg_type}: differs from {golden_path(msg_type)}'


def test_dependencies_are_named_as_the_msg_file_references_them():
    text = golden_path('nav_msgs/msg/Odometry').read_text()
    names = [part.splitlines()[0] for part in text.split(f'\n{SEPARATOR}\n')[1:]]
    assert names == ['MSG: geometry_msgs/PoseWithCovariance', 'MSG: geometry_msgs/Pose',
                     'MSG: geometry_msgs/Point', 'MSG: geometry_msgs/Quaternion',
                     'MSG: geometry_msgs/TwistWithCovariance', 'MSG: geometry_msgs/Twist',
                     'MSG: geometry_msgs/Vector3', 'MSG: std_msgs/Header',
                     'MSG: builtin_interfaces/Time']


def _prefix(tmp_path: Path, files: dict[str, str]) -> str:
    """An install prefix with an ament index entry per package and the given files."""
    for rel, text in files.items():
        path = tmp_path / 'share' / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(text.encode())
        index = tmp_path / 'share' / 'ament_index' / 'resource_index' / 'packages'
        index.mkdir(parents=True, exist_ok=True)
        (index / rel.split('/')[0]).touch()
    return str(tmp_path)


def test_definition_follows_rosbag2s_rules(tmp_path):
    sep = '=' * 80
    prefix = _prefix(tmp_path, {
        # comments kept; a same-package name gets the package; 'b_pkg/Leaf' kept as written;
        # wstring is no primitive to rosbag2 (looked up, not found: the .idl fallback)
        'a_pkg/msg/Root.msg': '# Root: Leaf is not a field here\nb_pkg/Leaf[] leaves  # c\n'
                              'Mid mid\nuint8 K=1\n',
        'a_pkg/msg/Mid.msg': 'b_pkg/msg/Leaf leaf\nfloat64[3] v\r\n',
        'b_pkg/msg/Leaf.msg': 'string<=5 s\nint32[<=2] n\n',
        'a_pkg/msg/Wide.msg': 'wstring w\n',
        'a_pkg/msg/Wide.idl': '#include "b_pkg/msg/Leaf.idl"\nmodule a_pkg {};\n',
        'b_pkg/msg/Leaf.idl': 'module b_pkg {};\n',
    })
    encoding, data = definition('a_pkg/msg/Root', [prefix])
    assert encoding == 'ros2msg'
    assert data == (
        b'# Root: Leaf is not a field here\nb_pkg/Leaf[] leaves  # c\nMid mid\nuint8 K=1\n'
        + f'\n{sep}\nMSG: a_pkg/Mid\n'.encode() + b'b_pkg/msg/Leaf leaf\nfloat64[3] v\r\n'
        + f'\n{sep}\nMSG: b_pkg/msg/Leaf\n'.encode() + b'string<=5 s\nint32[<=2] n\n'
        + f'\n{sep}\nMSG: b_pkg/Leaf\n'.encode() + b'string<=5 s\nint32[<=2] n\n')
    encoding, data = definition('a_pkg/msg/Wide', [prefix])
    assert encoding == 'ros2idl'
    assert data == (f'{sep}\nIDL: a_pkg/msg/Wide\n'.encode()
                    + b'#include "b_pkg/msg/Leaf.idl"\nmodule a_pkg {};\n'
                    + f'\n{sep}\nIDL: b_pkg/msg/Leaf\n'.encode() + b'module b_pkg {};\n')
    assert definition('a_pkg/msg/Nope', [prefix]) == ('unknown', b'')
    assert definition('a/b/c/d', [prefix]) == ('unknown', b'')
    # the writer records what definition() gives
    with BagWriter(tmp_path / 'bag', prefixes=[prefix]) as w:
        for k, t in enumerate(('a_pkg/msg/Root', 'a_pkg/msg/Wide', 'a_pkg/msg/Nope')):
            w.add_topic(f'/t{k}', t)
    from mcap.reader import make_reader
    with open(tmp_path / 'bag' / 'bag_0.mcap', 'rb') as fh:
        schemas = {s.name: (s.encoding, s.data) for s in
                   make_reader(fh).get_summary().schemas.values()}
    assert schemas == {t: definition(t, [prefix]) for t in
                       ('a_pkg/msg/Root', 'a_pkg/msg/Wide', 'a_pkg/msg/Nope')}


# ---------------------------------------------------------------------------- a recorded bag

def _foxglove_reader() -> Path:
    """test/foxglove_reader with its node_modules (npm ci when missing); fails the test when
    it cannot be set up."""
    node, npm = shutil.which('node'), shutil.which('npm')
    if node is None or npm is None:
        pytest.fail('the Foxglove reader needs Node.js (node and npm on PATH, 18 or newer)')
    stamp = FOXGLOVE / '.stamp'
    lock = FOXGLOVE / 'package-lock.json'
    if not stamp.is_file() or stamp.stat().st_mtime < lock.stat().st_mtime:
        out = subprocess.run([npm, 'ci', '--no-audit', '--no-fund'], cwd=FOXGLOVE,
                             capture_output=True, text=True, timeout=300)
        if out.returncode != 0:
            pytest.fail(f'npm ci in {FOXGLOVE} failed:\n{out.stdout}{out.stderr}')
        stamp.touch()
    return FOXGLOVE / 'read.mjs'


@pytest.fixture(scope='module')
def recorded_bag(tmp_path_factory) -> Path:
    """A bag of `clis run --condition async --episodes 2 --record BAG`, episodes of 4 s sim
    time (one process, to keep the test short: the recorder is the same node)."""
    tmp = tmp_path_factory.mktemp('readers')
    params = tmp / 'short.yaml'
    params.write_text('sim:\n  ros__parameters:\n    episode:\n      time_limit: 4.0\n'
                      '      wander_time: 0.5\n')
    bag = tmp / 'bag'
    out = subprocess.run([sys.executable, '-m', 'clis_app.cli', 'run', '--condition',
                          'async', '--episodes', '2', '--quiet', '--single-process', '--params',
                          str(params), '--out', str(tmp / 'run'), '--record', str(bag)],
                         capture_output=True, text=True, timeout=180)
    assert out.returncode == 0, out.stdout + out.stderr
    return bag


def _stamp_ns(msg) -> int | None:
    """``header.stamp`` (or ``clock``) of a decoded message in ns, None if it has neither."""
    header = getattr(msg, 'header', None)
    stamp = getattr(msg, 'clock', None) if header is None else header.stamp
    return None if stamp is None else stamp.sec * 1_000_000_000 + stamp.nanosec


@pytest.mark.ros
def test_recorded_bag_opens_in_foxglove_rosbags_and_mcap_ros2(recorded_bag):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    reader = _foxglove_reader()
    file = BagReader(recorded_bag).file
    topics = bag_topics(recorded_bag)
    counts = {t: info.count for t, info in topics.items()}
    assert {info.type for info in topics.values()} == RECORDED
    assert all(counts.values()) and counts['/clock'] > 20

    # Foxglove: the indexed reader, every schema parsed with {ros2: true}, every message decoded
    out = subprocess.run(['node', str(reader), str(file)], capture_output=True, text=True,
                         timeout=120)
    assert out.stdout, out.stderr
    fox = json.loads(out.stdout)
    print('\nFoxglove (@mcap/core 2.2.2, @foxglove/rosmsg 5.0.5, '
          '@foxglove/rosmsg2-serialization 3.1.0): messages decoded per topic')
    for topic, got in sorted(fox['topics'].items()):
        print(f'  {topic:<20} {got["type"]:<38} {got["decoded"]:>5} / {got["count"]}')
    bad = {name: err for name, err in fox['schemas'].items() if err != 'ok'}
    assert not bad, f'schemas Foxglove cannot parse: {bad}'
    assert fox['errors'] == [] and out.returncode == 0, out.stdout[-2000:] + out.stderr
    assert {t: got['decoded'] for t, got in fox['topics'].items()} == counts
    # (the indexed reader yields the messages in log-time order)
    fox_order = {t: [int(s) for s in got['stamps']] for t, got in fox['topics'].items()}
    fox_stamps = {t: sorted(s) for t, s in fox_order.items()}

    # rosbags: the folder through its rosbag2 Reader, types from the bag's own schemas
    store = get_typestore(Stores.EMPTY)
    rb_counts: dict[str, int] = {}
    rb_stamps: dict[str, list[int]] = {}
    with Reader(recorded_bag) as r:
        for c in r.connections:
            store.register(get_types_from_msg(c.msgdef.data, c.msgtype))
        for c, _, raw in r.messages():
            msg = store.deserialize_cdr(raw, c.msgtype)
            rb_counts[c.topic] = rb_counts.get(c.topic, 0) + 1
            if (ns := _stamp_ns(msg)) is not None:
                rb_stamps.setdefault(c.topic, []).append(ns)
    assert rb_counts == counts

    # mcap-ros2-support's decoder
    mc_counts: dict[str, int] = {}
    mc_stamps: dict[str, list[int]] = {}
    with open(file, 'rb') as fh:
        for _, channel, _, msg in make_reader(
                fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            mc_counts[channel.topic] = mc_counts.get(channel.topic, 0) + 1
            if (ns := _stamp_ns(msg)) is not None:
                mc_stamps.setdefault(channel.topic, []).append(ns)
    assert mc_counts == counts

    # the three decoders read the same sim-time stamps
    for stamps in (rb_stamps, mc_stamps):
        assert {t: sorted(s) for t, s in stamps.items()} == \
            {t: s for t, s in fox_stamps.items() if s}
    # sim time from 0, never back in receive order, tick by tick; odometry at the ticks
    clock = fox_order['/clock']
    assert clock[0] == 0 and all(b >= a for a, b in zip(clock, clock[1:]))
    ticks = sorted(set(clock))
    assert len({b - a for a, b in zip(ticks, ticks[1:])}) == 1, 'sim time skipped a tick'
    assert set(fox_stamps['/odom']) <= set(ticks)
