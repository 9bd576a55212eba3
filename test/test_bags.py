"""MCAP bags: record, read back, independent readers, replay timing, damage, and
offline learning equal to live learning. Real rclpy + Fast DDS in separate processes."""

from __future__ import annotations

import json
import os
from pathlib import Path
import shutil
import signal
import subprocess
import sys
import time

from clis_app.bags.mcap import (
    SEPARATOR,
    BagError,
    BagReader,
    BagWriter,
    bag_info,
    message_definition,
    qos_dict,
)
import numpy as np
import pytest
import yaml

REPO = Path(__file__).resolve().parent.parent
PUBLISHER = REPO / 'bench' / 'bag_publisher.py'
QOS = [qos_dict('keep_last', 10, 'reliable', 'volatile')]


def clis(*args: str, timeout: float = 120.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, '-m', 'clis_app.cli', *args], text=True,
                          capture_output=True, timeout=timeout)


def start_recorder(path: Path, *ros: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, '-m', 'clis_app.bags.recorder_node', '--ros-args',
                             '-p', f'recorder.path:={path}', '-p', 'use_sim_time:=false', *ros],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def stop(proc: subprocess.Popen, sig: int = signal.SIGINT) -> str:
    proc.send_signal(sig)
    out, _ = proc.communicate(timeout=20)
    return out


def wait_for_recorder(proc: subprocess.Popen, path: Path) -> None:
    deadline = time.monotonic() + 120                 # a hang guard (a loaded host is slow)
    while not (path / 'metadata.yaml').is_file():
        assert proc.poll() is None, proc.communicate()[0]
        assert time.monotonic() < deadline, 'the recorder did not start'
        time.sleep(0.1)


def publish(topics: int, rate: float, seconds: float, size: int = 20) -> dict:
    out = subprocess.run([sys.executable, str(PUBLISHER), '--topics', str(topics), '--rate',
                          str(rate), '--seconds', str(seconds), '--size', str(size)],
                         capture_output=True, text=True, timeout=90)
    assert out.returncode == 0, out.stdout + out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def _synthetic_bag(path: Path, n: int = 300, chunk: int = 4096) -> list[tuple[str, bytes, int]]:
    """A bag of raw payloads (the reader never decodes), small chunks; what was written."""
    written = []
    with BagWriter(path, chunk_size=chunk) as w:
        for topic in ('/a', '/b'):
            w.add_topic(topic, 'sensor_msgs/msg/JointState', QOS)
        for k in range(n):
            topic = '/a' if k % 3 else '/b'
            data = bytes([k % 251]) * (40 + k % 17)
            w.write(topic, data, 1_000_000_000 + 10_000_000 * k)
            written.append((topic, data, 1_000_000_000 + 10_000_000 * k))
    return written


# ---------------------------------------------------------------------------- format

def test_schema_is_the_full_ros2msg_definition():
    text = message_definition('sensor_msgs/msg/JointState')
    head, *deps = text.split('\n' + SEPARATOR + '\n')
    assert 'string[] name' in head and 'float64[] position' in head
    names = [d.splitlines()[0] for d in deps]
    assert names == ['MSG: std_msgs/Header', 'MSG: builtin_interfaces/Time']
    assert 'int32 sec' in deps[1] and 'uint32 nanosec' in deps[1]
    with pytest.raises(BagError, match='no msg/Nope.msg'):
        message_definition('sensor_msgs/msg/Nope')


def test_synthetic_bag_reads_back_with_metadata(tmp_path):
    written = _synthetic_bag(tmp_path / 'syn')
    got = [(m.topic, m.data, m.log_ns) for m in BagReader(tmp_path / 'syn').messages()]
    assert got == written
    meta = yaml.safe_load((tmp_path / 'syn' / 'metadata.yaml').read_text())
    info = meta['rosbag2_bagfile_information']
    assert info['version'] == 9 and info['storage_identifier'] == 'mcap'
    assert info['relative_file_paths'] == ['syn_0.mcap']
    assert info['message_count'] == len(written)
    counts = {t['topic_metadata']['name']: t['message_count']
              for t in info['topics_with_message_count']}
    assert counts == {'/a': 200, '/b': 100}
    assert info['duration']['nanoseconds'] == 10_000_000 * (len(written) - 1)
    with pytest.raises(BagError, match='holds a bag already'):
        BagWriter(tmp_path / 'syn')


def test_truncated_and_corrupt_bags_say_what_and_keep_the_rest(tmp_path):
    _synthetic_bag(tmp_path / 'good')
    good = tmp_path / 'good' / 'good_0.mcap'
    size = good.stat().st_size
    # truncated in the middle: a clear error naming the file, every earlier chunk readable
    cut = tmp_path / 'cut.mcap'
    cut.write_bytes(good.read_bytes()[:size // 2])
    reader = BagReader(cut)
    got = []
    with pytest.raises(BagError, match=r'cut\.mcap: truncated'):
        for m in reader.messages():
            got.append(m)
    assert 0 < len(got) < 300
    assert [m.log_ns for m in got] == [1_000_000_000 + 10_000_000 * k for k in range(len(got))]
    info = bag_info(cut)
    assert info.damage and info.message_count == len(got)
    # clis bag info says so, exit code 1
    out = clis('bag', 'info', str(cut))
    assert out.returncode == 1
    assert 'DAMAGED' in out.stdout and f'Readable:          {len(got)} messages' in out.stdout
    # corrupt bytes inside the middle chunk: the CRC (or the decompression) catches it
    from mcap.reader import make_reader
    with open(good, 'rb') as fh:
        chunks = make_reader(fh).get_summary().chunk_indexes
    assert len(chunks) > 2
    mid = chunks[len(chunks) // 2]
    at = mid.chunk_start_offset + mid.chunk_length // 2
    bad = tmp_path / 'bad.mcap'
    raw = bytearray(good.read_bytes())
    raw[at: at + 8] = bytes(255 - b for b in raw[at: at + 8])
    bad.write_bytes(bytes(raw))
    got = []
    with pytest.raises(BagError, match=r'bad\.mcap: (corrupt|truncated)') as exc:
        for m in BagReader(bad).messages():
            got.append(m)
    assert 'readable' in str(exc.value)
    assert 0 < len(got) < 300
    # not a bag at all
    with pytest.raises(BagError, match='no such bag'):
        BagReader(tmp_path / 'nothing')


# ---------------------------------------------------------------------------- recorder

@pytest.mark.ros
def test_recorder_round_trip_no_loss_and_independent_readers(tmp_path):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from rclpy.serialization import deserialize_message
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    from sensor_msgs.msg import JointState

    bag = tmp_path / 'rec'
    rec = start_recorder(bag, '-p', 'recorder.flush_interval:=0.2')
    wait_for_recorder(rec, bag)
    # a bounded stream at a rate any host keeps up with; whether the recorder keeps up with a
    # heavy load (and how fast) is bench/bench_bag.py's measure, not a test's
    pub = publish(topics=6, rate=25.0, seconds=2.0, size=20)
    out = stop(rec)
    assert rec.returncode == 0, out
    n = pub['per_topic']
    topics = [f'/load/t{k}' for k in range(6)]

    # our reader: every message equal to what was published, each topic in publication order
    # (its index), none twice; its header stamp is its publication time, before its receipt
    seen: dict[str, list[float]] = {t: [] for t in topics}
    reader = BagReader(bag)
    for m in reader.messages():
        msg = deserialize_message(m.data, JointState)
        assert list(msg.name) == ['seq'] and list(msg.velocity) == [0.5] * 20
        seen[m.topic].append(msg.position[0])
        stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        assert stamp_ns <= m.publish_ns + 5_000_000 and m.publish_ns <= m.log_ns + 5_000_000
    for t in topics:
        assert seen[t] and all(b > a for a, b in zip(seen[t], seen[t][1:])), \
            f'{t}: reordered or repeated messages'
        assert set(seen[t]) <= {float(i) for i in range(n)}, t
    total = sum(len(v) for v in seen.values())
    assert sum(reader.topics[t].count for t in topics) == total
    assert reader.complete and reader.damage is None
    info = reader.topics['/load/t0']
    assert info.type_hash.startswith('RIHS01_') and len(info.type_hash) == 7 + 64
    assert info.qos_profiles[0]['reliability'] == 'reliable'

    # rosbags (an independent rosbag2 reader) opens the folder and decodes every message
    store = get_typestore(Stores.EMPTY)
    count = 0
    with Reader(bag) as r:
        for c in r.connections:
            store.register(get_types_from_msg(c.msgdef.data, c.msgtype))
        assert {c.topic for c in r.connections} == set(topics)
        assert all(c.ext.offered_qos_profiles for c in r.connections)
        for c, _, raw in r.messages():
            msg = store.deserialize_cdr(raw, c.msgtype)
            assert msg.name == ['seq']
            count += 1
    assert count == total
    # the mcap library's ROS 2 decoder too
    count = 0
    with open(reader.file, 'rb') as fh:
        for _, channel, _, decoded in make_reader(
                fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            assert list(decoded.velocity) == [0.5] * 20 and channel.topic in topics
            count += 1
    assert count == total


@pytest.mark.ros
def test_killed_recorder_leaves_the_bag_readable_to_its_last_chunk(tmp_path):
    bag = tmp_path / 'crash'
    rec = start_recorder(bag, '-p', 'recorder.flush_interval:=0.1',
                         '-p', 'recorder.topics:=/load/t0')
    wait_for_recorder(rec, bag)
    pub = publish(topics=1, rate=100.0, seconds=1.0)

    def flushed() -> bool:          # what is on disk now: every message in a complete chunk
        try:
            meta = yaml.safe_load((bag / 'metadata.yaml').read_text())
            return (bag_info(bag).topics['/load/t0'].count == pub['per_topic'] and
                    meta['rosbag2_bagfile_information']['message_count'] == pub['per_topic'])
        except (KeyError, TypeError, OSError, ValueError, yaml.YAMLError):
            return False
    deadline = time.monotonic() + 60                  # a hang guard, not a window
    while not flushed():
        assert time.monotonic() < deadline and rec.poll() is None, 'never flushed'
        time.sleep(0.05)
    stop(rec, signal.SIGKILL)
    info = bag_info(bag)
    assert info.damage and 'footer' in info.damage
    assert info.topics['/load/t0'].count == pub['per_topic']
    meta = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert meta['message_count'] == pub['per_topic']


# ---------------------------------------------------------------------------- replay

@pytest.mark.ros
def test_replay_reproduces_sequence_and_timing(tmp_path):
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState

    bag = tmp_path / 'rp'
    rng = np.random.default_rng(3)
    gaps = rng.uniform(0.002, 0.03, size=120)              # irregular, 2-30 ms
    times = 1_700_000_000_000_000_000 + np.cumsum(gaps * 1e9).astype(np.int64)
    sent = []
    with BagWriter(bag) as w:
        w.add_topic('/rp/a', 'sensor_msgs/msg/JointState', QOS)
        w.add_topic('/rp/b', 'sensor_msgs/msg/JointState', QOS)
        for k, t in enumerate(times):
            topic = '/rp/a' if k % 2 else '/rp/b'
            w.write(topic, _cdr(k), int(t))
            sent.append((topic, float(k), int(t)))
    context = rclpy.context.Context()
    rclpy.init(context=context)
    node = rclpy.create_node('replay_probe', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    got: list[tuple[str, float, int]] = []
    clocks: list[int] = []
    for topic in ('/rp/a', '/rp/b'):
        node.create_subscription(JointState, topic, lambda m, info, t=topic: got.append(
            (t, m.position[0], info['source_timestamp'])), 100)
    node.create_subscription(Clock, '/clock', lambda m: clocks.append(
        m.clock.sec * 1_000_000_000 + m.clock.nanosec), 100)
    proc = subprocess.Popen([sys.executable, '-m', 'clis_app.cli', 'replay', str(bag),
                             '--quiet', '--wait-for-subscribers', '--delay', '0.5'],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 120             # hang guards, not windows
        while len(got) < len(sent) and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.01)
        out, _ = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=context)
    assert proc.returncode == 0, out
    for topic in ('/rp/a', '/rp/b'):                         # each topic's sequence
        assert [k for t, k, _ in got if t == topic] == [k for t, k, _ in sent if t == topic]
    assert len(got) == len(sent), f'{len(got)} of {len(sent)} messages replayed'
    # the replay published them in the recorded order (the source stamps DDS gives the
    # subscriber: when the replay published each); how close to the recorded timing is
    # bench/bench_bag.py's measure (wall time, not a test's)
    at = {(t, k): r for t, k, r in got}
    published = [at[(t, k)] for t, k, _ in sent]
    assert all(b >= a for a, b in zip(published, published[1:])), 'replayed out of order'
    assert clocks == sorted(clocks), '/clock went back'
    assert clocks and min(clocks) >= int(times[0]) and max(clocks) <= int(times[-1])


def _cdr(k: int) -> bytes:
    """The exact CDR of JointState(name=['k'], position=[k]) (rclpy's serializer pads)."""
    return (bytes.fromhex('00010000') + bytes(8) + bytes.fromhex('01000000') + b'\0\0\0\0'
            + bytes.fromhex('0100000002000000') + b'k\0\0\0' + bytes.fromhex('01000000')
            + np.float64(k).tobytes() + bytes(8))


# ---------------------------------------------------------------------------- offline learning

@pytest.mark.ros
def test_offline_learning_from_a_recorded_run_equals_the_live_learner(tmp_path):
    run, bag = tmp_path / 'run', tmp_path / 'bags' / 'view3'
    short = tmp_path / 'short.yaml'                    # episodes of 20 s: a third of the work
    short.write_text('/**:\n  ros__parameters:\n    episode: {time_limit: 20.0}\n')
    out = clis('run', '--condition', 'view', '--episodes', '3', '--quiet', '--out', str(run),
               '--record', str(bag), '--params', str(short), timeout=240)
    assert out.returncode == 0, out.stdout + out.stderr
    info = bag_info(bag)
    assert info.damage is None and info.custom_data['condition'] == 'view'
    # no message lost at the graph's rates: every publication sequence number is there
    seqs: dict[str, list[int]] = {}
    for m in BagReader(bag).messages():
        seqs.setdefault(m.topic, []).append(m.sequence)
    # (a volatile topic's first messages may go out before DDS has matched the new
    # publisher with the recorder -- or any other subscriber: the simulator's /clock and
    # sensor streams start at once; that is discovery, not loss at the rate)
    for topic in ('/clock', '/ir', '/camera', '/reward', '/cmd_vel', '/view/proposal',
                  '/arbiter/action', '/episode'):
        s = np.sort(seqs[topic])
        assert np.all(np.diff(s) == 1), f'{topic}: messages lost'
    for topic in ('/view/proposal', '/arbiter/action', '/episode'):
        assert min(seqs[topic]) == 1, f'{topic}: the first messages are missing'
    ckpt = tmp_path / 'offline.npz'
    res = clis('learn', str(bag), '--out', str(ckpt))
    assert res.returncode == 0, res.stderr
    assert 'clis learn: 3 episodes learned' in res.stderr
    live, off = np.load(run / 'checkpoint.npz'), np.load(ckpt)
    for key in ('view.w', 'view.W', 'view.sigma'):
        np.testing.assert_allclose(off[key], live[key], rtol=1e-9, atol=1e-12, err_msg=key)
    assert np.abs(off['view.w']).max() > 0                     # it did learn something
    # the offline checkpoint is what `clis run --resume` takes (same modules and hash)
    meta_live = json.loads(str(live['__meta__']))
    meta_off = json.loads(str(off['__meta__']))
    assert meta_off['params_hash'] == meta_live['params_hash']
    assert meta_off['extra']['version'] == meta_live['extra']['version'] == 3
    # ... exactly as the learner node loads `learner_node.resume`
    from clis_learner.core.checkpoint import load_checkpoint
    from clis_learner.core.config import (
        DEFAULT_PRESET,
        load_clis_params,
        params_hash,
        preset_overrides,
    )
    from clis_modules.core.modules import arena_map, make_modules
    from cr_sim.core.arena import load_arena
    clis_params = load_clis_params(overrides=preset_overrides(DEFAULT_PRESET))  # clis run's
    mods = make_modules(clis_params, 'view', *arena_map(load_arena(None)))
    meta = load_checkpoint(ckpt, mods, params_hash(clis_params))
    assert meta['extra']['version'] == 3
    np.testing.assert_array_equal(mods[0].W, off['view.W'])
    # a bag of another condition's modules is refused with the reason
    res = clis('learn', str(bag), '--condition', 'nope', '--out', str(ckpt))
    assert res.returncode == 2 and 'condition' in res.stderr
    shutil.rmtree(bag)
    os.sync()
