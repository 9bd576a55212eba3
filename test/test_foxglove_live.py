"""The live view (``clis run --foxglove PORT``, docs/foxglove.md) as the Foxglove app sees it.

A short Async run serves its topics on a Foxglove WebSocket. A client speaking the Foxglove
WebSocket protocol v1 (``foxglove.websocket.v1``, which foxglove-sdk's server names
``foxglove.sdk.v1``; the client is the ``websockets`` package, not the SDK that serves)
subscribes to every channel the server advertises and decodes each message with the advertised
``ros2msg`` schema (``mcap_ros2``'s decoder, an independent reader). Judged on what arrived:
every channel has messages that decode, each schema is the bag's text, the sim-time stamps of
``/clock`` never go back, the derived success rate agrees with the run's ``episodes.csv``, and the
server listens on 127.0.0.1 only (``/proc/net/tcp*`` of the node's own sockets).

The run also records its bag (``--record``: every message of every topic, as published) and
serves the view with ``foxglove.max_rate`` lowered to :data:`MAX_RATE` (``--params``), so that the
decimation shows at any speed of the graph, with ``--foxglove-wait`` (the first episode waits
for the client, so that a short run on a fast host is seen from its start): a decimated topic's
messages arrive as published, in sim-time order, a subset of the bag's; every message of the
other topics arrives (the bag's, from the first one the client got to the last; the learner's
progress of every episode of ``episodes.csv``, the episode events of each).
"""

from __future__ import annotations

import csv
import json
import os
from pathlib import Path
import socket
import struct
import subprocess
import sys
import time

from clis_app.bags.mcap import BagReader, bag_topics, message_definition
from clis_app.live.foxglove_node import CONFIG_FILE
from clis_app.live.layout import (
    LAYOUT_CONDITION,
    LAYOUT_FILE,
    PATH_TOPIC,
    SUCCESS_TOPIC,
    layout_json,
    shown_topics,
)
from clis_base.params import config_dir, ros_parameters
from mcap.records import Schema
from mcap_ros2.decoder import DecoderFactory
from nav_msgs.msg import Odometry
import pytest
from rclpy.serialization import deserialize_message
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

pytestmark = pytest.mark.ros

#: The protocol ``foxglove.websocket.v1`` under the name foxglove-sdk's server negotiates
#: (the same messages; the SDK refuses a client that offers only the old name, with HTTP 400).
#: The client offers both names, as the Foxglove app does.
SUBPROTOCOL = 'foxglove.sdk.v1'
OFFERED = [SUBPROTOCOL, 'foxglove.websocket.v1']
#: Topics the layout shows: each must be advertised and delivered during the run.
EXPECTED = {'/clock', '/odom', '/arena', '/markers', '/reward', '/episode', '/cmd_vel',
            '/arbiter/selection', '/arbiter/action', '/place/belief', '/learner/progress',
            PATH_TOPIC, SUCCESS_TOPIC}
LISTEN = '0A'                                                      # TCP_LISTEN
#: foxglove.max_rate of the test's run [1/s wall]: a few messages per wall second, fewer than
#: the sim's 20 Hz ticks even at a real-time factor of 1 (the default, 30, is for the app).
MAX_RATE = 2.0
#: The topics forwarded at most ``foxglove.max_rate`` per wall second (the shipped config, and
#: the proposals of the run's modules).
DECIMATED = frozenset('/' + t.strip().lstrip('/') for t in ros_parameters(
    config_dir() / CONFIG_FILE, '/**')['foxglove']['decimated'].split(',') if t.strip()) | {
        '/innate/proposal', '/view/proposal', '/place/proposal'}
#: Transient-local topics (a late subscriber gets their last messages again).
LATCHED = frozenset({'/episode', '/learner/progress', '/innate/params', '/view/params',
                     '/place/params', '/arena'})
#: Topics of which every message is served (low rate or transient local).
EVERY = ('/arbiter/selection', '/place/belief', '/episode', '/learner/progress',
         '/innate/params', '/view/params', '/place/params', '/arena')
UNKNOWN = 'Unknown channel ID: '


def free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def listening(pid: int, port: int) -> list[str]:
    """The local addresses (hex, as /proc/net/tcp* write them) of every listening TCP socket
    of process ``pid``, and of any process's listening socket on ``port``."""
    inodes = set()
    for fd in Path(f'/proc/{pid}/fd').iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue
        if target.startswith('socket:['):
            inodes.add(target[len('socket:['):-1])
    out = []
    for table in ('/proc/net/tcp', '/proc/net/tcp6'):
        for line in Path(table).read_text().splitlines()[1:]:
            f = line.split()
            local, state, inode = f[1], f[3], f[9]
            if state == LISTEN and (inode in inodes or int(local.split(':')[1], 16) == port):
                out.append(local)
    return out


def logs(out: Path) -> str:
    return '\n'.join(f'--- {log.name}:\n' + log.read_text(errors='replace')[-2000:]
                     for log in sorted((out / 'logs').glob('*.log')))


def node_pid(parent: int) -> int:
    out = subprocess.run(['pgrep', '-P', str(parent), '-f', '/lib/clis_app/foxglove( |$)'],
                         capture_output=True, text=True).stdout.split()
    assert len(out) == 1, out
    return int(out[0])


@pytest.fixture(scope='module')
def live(tmp_path_factory):
    """A 2-episode run with the live view, watched from its start to its end."""
    out = tmp_path_factory.mktemp('foxglove') / 'run'
    bag = out.parent / 'bag'
    params = out.parent / 'foxglove.yaml'
    params.write_text(f'/**:\n  ros__parameters:\n    foxglove:\n      max_rate: {MAX_RATE}\n')
    port = free_port()
    proc = subprocess.Popen([sys.executable, '-m', 'clis_app.cli', 'run', '--out', str(out),
                             '--quiet', '--condition', 'async', '--episodes', '2', '--seed', '1',
                             '--foxglove', str(port), '--foxglove-wait', '--record', str(bag),
                             '--params', str(params)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    seen = {'channels': {}, 'messages': {}, 'listen': None, 'protocol': None, 'info': None,
            'other': [], 'retried': []}
    try:
        ws = None
        deadline = time.monotonic() + 60
        while ws is None:
            try:
                ws = connect(f'ws://127.0.0.1:{port}', subprotocols=OFFERED,
                             open_timeout=2, max_size=None)
            except OSError as exc:
                if proc.poll() is not None or time.monotonic() > deadline:
                    proc.kill()
                    pytest.fail(f'no live view on port {port} ({exc}):\n'
                                f'{proc.communicate()[0]}\n{logs(out)}')
                time.sleep(0.2)
        seen['protocol'] = ws.subprotocol
        seen['listen'] = listening(node_pid(proc.pid), port)
        subs = {}                                            # subscription id -> channel id
        with ws:
            while True:
                try:
                    frame = ws.recv(timeout=120)
                except (ConnectionClosed, TimeoutError):
                    break
                if isinstance(frame, str):
                    msg = json.loads(frame)
                    if msg['op'] == 'serverInfo':
                        seen['info'] = msg
                    elif msg['op'] == 'advertise':
                        new = []
                        for ch in msg['channels']:
                            seen['channels'][ch['id']] = ch
                            subs[len(subs) + 1] = ch['id']
                            new.append({'id': len(subs), 'channelId': ch['id']})
                        ws.send(json.dumps({'op': 'subscribe', 'subscriptions': new}))
                    elif msg['op'] == 'status' and msg['message'].startswith(UNKNOWN):
                        # foxglove-sdk 0.30.3 refuses, now and then, a channel created while
                        # the client connected; it knows it a moment later: once more
                        cid = int(msg['message'][len(UNKNOWN):])
                        assert cid in seen['channels'] and cid not in seen['retried'], msg
                        seen['retried'].append(cid)
                        time.sleep(0.2)
                        subs[len(subs) + 1] = cid
                        ws.send(json.dumps({'op': 'subscribe', 'subscriptions': [
                            {'id': len(subs), 'channelId': cid}]}))
                    else:
                        seen['other'].append(msg)
                elif frame[0] == 0x01:                       # message data
                    sub, log_ns = struct.unpack_from('<IQ', frame, 1)
                    seen['messages'].setdefault(subs[sub], []).append((log_ns, frame[13:]))
        code = proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
        text = proc.communicate()[0]
    seen.update(code=code, text=text, out=out, port=port, bag=bag)
    return seen


def received(live: dict) -> dict[str, list[bytes]]:
    """Topic -> the payloads the client got, in order."""
    return {live['channels'][cid]['topic']: [data for _, data in msgs]
            for cid, msgs in live['messages'].items()}


def recorded(live: dict, with_log_ns: bool = False) -> dict[str, list]:
    """Topic -> the payloads of the run's bag, in the order recorded (published); with
    ``with_log_ns``, (the time the recorder got it [ns], payload) pairs."""
    out: dict[str, list] = {}
    for m in BagReader(live['bag']).messages():
        data = bytes(m.data)
        out.setdefault(m.topic, []).append((m.log_ns, data) if with_log_ns else data)
    return out


def stamp(msg) -> int:
    t = msg.clock if hasattr(msg, 'clock') else msg.header.stamp
    return t.sec * 10**9 + t.nanosec


def decoded(live: dict) -> dict[str, list]:
    """Every message received, decoded with its channel's advertised schema: topic -> msgs."""
    factory = DecoderFactory()
    out = {}
    for cid, msgs in live['messages'].items():
        ch = live['channels'][cid]
        assert ch['encoding'] == 'cdr' and ch['schemaEncoding'] == 'ros2msg', ch
        decode = factory.decoder_for('cdr', Schema(id=cid, name=ch['schemaName'],
                                                   encoding='ros2msg',
                                                   data=ch['schema'].encode()))
        out[ch['topic']] = [decode(data) for _, data in msgs]
    return out


def test_every_advertised_channel_decodes_with_its_schema(live):
    assert live['code'] == 0, live['text']
    print('messages per channel:', {ch['topic']: len(live['messages'].get(c, []))
                                    for c, ch in sorted(live['channels'].items())})
    assert live['protocol'] == SUBPROTOCOL
    topics = {ch['topic'] for ch in live['channels'].values()}
    assert EXPECTED <= topics, EXPECTED - topics
    silent = [live['channels'][c]['topic'] for c in live['channels']
              if not live['messages'].get(c)]
    assert not silent, f'advertised but nothing arrived: {silent}; {live["other"][:5]}'
    msgs = decoded(live)
    for ch in live['channels'].values():                 # the bags' schema, byte for byte
        assert ch['schema'] == message_definition(ch['schemaName']), ch['topic']
    # sim time: /clock never goes back (it holds at the gates) and covers the learned episodes
    clock = [m.clock.sec + 1e-9 * m.clock.nanosec for m in msgs['/clock']]
    back = [(a, b) for a, b in zip(clock, clock[1:]) if b < a]
    assert not back, back[:5]
    end = msgs[SUCCESS_TOPIC][-1].header.stamp
    assert clock[-1] >= end.sec + 1e-9 * end.nanosec > clock[0]
    assert all(m.header.frame_id == 'odom' for m in msgs['/odom'])
    assert {m.header.frame_id for m in msgs['/arbiter/selection']} <= {'innate', 'view',
                                                                        'place'}
    for m in msgs['/arbiter/selection']:
        assert abs(sum(m.position) - 1.0) < 1e-9
    assert msgs['/arena'][-1].markers, 'the arena has markers'


def test_derived_success_rate_and_path_agree_with_the_run(live):
    assert live['code'] == 0, live['text']
    msgs = decoded(live)
    with open(live['out'] / 'episodes.csv', newline='') as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 2
    last = msgs[SUCCESS_TOPIC][-1].vector
    assert last.y == len(rows)
    assert last.x == pytest.approx(sum(float(r['reached']) for r in rows) / len(rows))
    assert last.z == float(rows[-1]['reached'])
    paths = msgs[PATH_TOPIC]
    for path in paths:                                   # one episode's path each
        assert path.header.frame_id == 'odom' and path.poses
        step = [((b.pose.position.x - a.pose.position.x) ** 2
                 + (b.pose.position.y - a.pose.position.y) ** 2) ** 0.5
                for a, b in zip(path.poses, path.poses[1:])]
        assert all(d >= 0.02 - 1e-9 for d in step)        # foxglove.path_step
    # each pose is the odometry of its instant: the path is built from the odom messages the
    # view forwards (decimated), not from those the client got, so it is judged against every
    # odom message of the run, the bag's (the recorder, a subscriber too, may miss one on a
    # loaded host: most poses must be found, and each one found must be equal)
    odom = {(m.header.stamp.sec, m.header.stamp.nanosec): m.pose.pose.position
            for m in (deserialize_message(d, Odometry) for d in recorded(live)['/odom'])}
    poses = [p for path in paths for p in path.poses]
    found = [p for p in poses if (p.header.stamp.sec, p.header.stamp.nanosec) in odom]
    assert poses and 2 * len(found) >= len(poses), (len(found), len(poses))
    for p in found:
        q = odom[p.header.stamp.sec, p.header.stamp.nanosec]
        assert (q.x, q.y) == (p.pose.position.x, p.pose.position.y), p.header.stamp


def test_the_server_listens_on_loopback_only(live):
    assert live['info']['name'] == 'clis'
    addresses = live['listen']
    assert any(int(a.split(':')[1], 16) == live['port'] for a in addresses), addresses
    loopback = {'0100007F', '00000000000000000000000001000000'}
    assert all(a.split(':')[0] in loopback for a in addresses), addresses


def test_the_shipped_layout_is_the_models_and_shows_served_topics(repo, live):
    text = (repo / 'config' / 'foxglove_layout.json').read_text()
    assert text == layout_json(), 'regenerate: python -c "from clis_app.live.layout ' \
                                  'import layout_json; print(layout_json(), end=\'\')"'
    shown = shown_topics(json.loads(text))
    assert shown and shown <= EXPECTED, shown - EXPECTED
    # the run's (async) layout, written into its folder by the live view
    assert LAYOUT_CONDITION == 'async'
    assert (live['out'] / LAYOUT_FILE).read_text() == text


def panel(layout: object, title: str) -> dict:
    """The panel of a layout (parsed JSON) with that title."""
    found = []

    def walk(node: object) -> None:
        if isinstance(node, dict):
            if node.get('type') == 'panel' and node.get('title', '').startswith(title):
                found.append(node)
            for v in node.values():
                walk(v)
        elif isinstance(node, list):
            for v in node:
                walk(v)
    walk(layout)
    assert len(found) <= 1, found
    return found[0] if found else {}


def test_the_layout_of_a_condition_names_each_of_its_modules():
    """The live view's layout follows its condition: a line of Pr(i | x) for each module, in
    the order of arbiter/selection's position, and the belief grids of their plug-ins."""
    four = json.loads(layout_json('async:innate+view+place+wall'))
    paths = panel(four, 'Pr(i | x)')['config']['paths']
    assert [(p['label'], p['value']) for p in paths] == [
        (f'Pr({m} | x)', f'/arbiter/selection.position[{k}]')
        for k, m in enumerate(('innate', 'view', 'place', 'wall'))]
    assert list(panel(four, "Place module's belief")['config']['topics']) == [
        '/place/belief', '/arena']
    two = json.loads(layout_json('sync:wall+innate'))
    assert [p['label'] for p in panel(two, 'Pr(i | x)')['config']['paths']] == [
        'Pr(wall | x)', 'Pr(innate | x)']
    assert not panel(two, "Place module's belief") and '/place/belief' not in shown_topics(two)


def test_decimated_topics_arrive_as_published_in_sim_time_order(live):
    assert live['code'] == 0, live['text']
    got, bag, msgs = received(live), recorded(live), decoded(live)
    shown = sorted(DECIMATED & set(got))
    assert {'/clock', '/odom', '/reward', '/markers'} <= set(shown), shown
    fewer = []
    for topic in shown:
        # the graph's own messages, in the order published: those the bag holds too (the
        # recorder is a subscriber as well, and may miss some on a loaded host) are a
        # subsequence of the bag, none repeated or reordered
        held = [d for d in got[topic] if d in bag[topic]]
        it = iter(bag[topic])
        assert held and all(any(d == b for b in it) for d in held), topic
        stamps = [stamp(m) for m in msgs[topic]] if topic != '/markers' else [
            stamp(m.markers[0]) for m in msgs[topic] if m.markers]
        assert stamps == sorted(stamps), topic                  # sim time never goes back
        if topic in ('/odom', '/reward'):     # once per tick (the clock holds at the gates,
            # a module resends a proposal, the simulator an instant's readings: the same
            # message again): one message per stamp
            assert len(set(zip(stamps, got[topic]))) == len(set(stamps)), topic
        # decimated: of the messages published from the first received to the last, fewer
        first, last = bag[topic].index(held[0]), bag[topic].index(held[-1])
        if len(held) < last - first + 1:
            fewer.append(topic)
    print('decimated, received / recorded:',
          {t: f'{len(got[t])}/{len(bag[t])}' for t in shown})
    assert set(fewer) >= {'/clock', '/odom', '/reward'}, fewer


def test_every_message_of_the_low_rate_topics_arrives(live):
    assert live['code'] == 0, live['text']
    got, bag, msgs = received(live), recorded(live), decoded(live)
    # the run stops its nodes, the view with them, once the learner has reported the last
    # episode: what is published after that report (the next episode's start) may not be
    # served any more; everything up to it is
    logged = recorded(live, with_log_ns=True)
    end = max(ns for ns, _ in logged['/learner/progress'])
    for topic in EVERY:
        mine = got.get(topic)
        assert mine, topic
        # and the last thing published, the next episode's start, may reach the view but not
        # the recorder: the simulator is stopped first, and a reliable writer that is gone
        # repairs no loss. Such messages end the client's stream.
        recorded_ = set(bag[topic])
        k = next((i for i, d in enumerate(mine) if d not in recorded_), len(mine))
        assert all(d not in recorded_ for d in mine[k:]) and len(mine) - k <= 1, \
            (topic, 'received, never recorded, before the end', len(mine) - k)
        mine = mine[:k]
        assert mine, topic
        first = min(bag[topic].index(d) for d in mine)
        upto = [d for ns, d in logged[topic][first:] if ns <= end]
        if topic in LATCHED:
            # sent again to a late subscriber (the last foxglove.replay): once more, maybe
            assert set(upto) <= set(mine) <= set(bag[topic][first:]), \
                (topic, len(mine), len(upto), len(bag[topic]))
        else:                                   # subscribed when the client did: from then on
            assert mine == bag[topic][first:first + len(mine)] and len(mine) >= len(upto), \
                (topic, len(mine), len(upto), len(bag[topic]), first)
        if topic in ('/episode', '/learner/progress'):
            assert first == 0, topic                            # all of the run's
    # every episode of the run: its progress row and its start and end events
    with open(live['out'] / 'episodes.csv', newline='') as fh:
        rows = list(csv.DictReader(fh))
    episodes = [r['episode'] for r in rows]
    progress = {}
    for m in msgs['/learner/progress']:
        values = {kv.key: kv.value for kv in m.status[0].values}
        if values.get('learned') == '1':
            progress[str(int(float(values['episode'])))] = values
    assert sorted(progress) == sorted(episodes), (progress.keys(), episodes)
    for r in rows:
        assert float(progress[r['episode']]['reached']) == float(r['reached'])
    events = {(m.status[0].message, kv.value) for m in msgs['/episode']
              for kv in m.status[0].values if kv.key == 'episode'}
    for r in rows:                                      # the start and the end of each episode
        assert ('start', r['episode']) in events, (r['episode'], events)
        end = 'reached' if float(r['reached']) else 'timeout'
        assert (end, r['episode']) in events, (r['episode'], events)
    print('every message, received / recorded:',
          {t: f'{len(got[t])}/{len(bag[t])}' for t in EVERY})


def test_a_run_of_four_modules_records_and_lays_out_each_of_them(tmp_path):
    """``clis run`` of async:innate+view+place+wall: its bag holds every module's proposals
    (the recorder's topics are the condition's) and the layout its live view writes into the
    run's folder names every module."""
    condition, four = 'async:innate+view+place+wall', ('innate', 'view', 'place', 'wall')
    out, bag = tmp_path / 'run', tmp_path / 'bag'
    short = tmp_path / 'short.yaml'
    short.write_text('/**:\n  ros__parameters:\n    episode: {time_limit: 10.0}\n')
    proc = subprocess.run([sys.executable, '-m', 'clis_app.cli', 'run', '--out', str(out),
                           '--quiet', '--condition', condition, '--episodes', '1', '--seed', '1',
                           '--speed', '0', '--foxglove', str(free_port()), '--record', str(bag),
                           '--params', str(short)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr + logs(out)
    counts = {topic: info.count for topic, info in bag_topics(bag).items()}
    for m in four:
        assert counts.get(f'/{m}/proposal', 0) > 0, (m, counts)
    assert counts.get('/place/belief', 0) > 0, counts
    text = (out / LAYOUT_FILE).read_text()
    assert text == layout_json(condition)
    assert [p['label'] for p in panel(json.loads(text), 'Pr(i | x)')['config']['paths']] == [
        f'Pr({m} | x)' for m in four]
