"""A Foxglove WebSocket client that subscribes to every channel of a live view and counts.

What the Foxglove app costs the live view (``clis run --foxglove PORT``, docs/foxglove.md)
when every topic is shown: it connects (waiting up to ``--wait`` s for the server), subscribes
to every channel as it is advertised, and after ``--seconds`` (or when the server closes)
prints the messages and bytes received per channel. docs/benchmarks.md runs it next to
``bench/bench_graph.py --cpu-only --foxglove PORT``.

    python bench/foxglove_client.py --port 8765 --seconds 60 [--topics layout]
"""

from __future__ import annotations

import argparse
import json
import struct
import time

from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

#: The Foxglove WebSocket protocol v1 under its two names (foxglove-sdk's server: the first).
SUBPROTOCOLS = ['foxglove.sdk.v1', 'foxglove.websocket.v1']
UNKNOWN = 'Unknown channel ID: '


def watch(port: int, seconds: float, wait: float = 120.0,
          only: frozenset[str] = frozenset()) -> dict[str, tuple[int, int]]:
    """Topic -> (messages, payload bytes) received in ``seconds`` from the first connection,
    for every channel advertised (subscribed to: those of ``only``, or all)."""
    deadline = time.monotonic() + wait
    while True:
        try:
            ws = connect(f'ws://127.0.0.1:{port}', subprotocols=SUBPROTOCOLS, open_timeout=2,
                         max_size=None)
            break
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.5)
    topics: dict[int, str] = {}                          # subscription id -> topic
    named: dict[int, str] = {}                           # channel id -> topic
    counts: dict[str, list[int]] = {}
    end = time.monotonic() + seconds
    with ws:
        while (left := end - time.monotonic()) > 0:
            try:
                frame = ws.recv(timeout=left)
            except (ConnectionClosed, TimeoutError):
                break
            if isinstance(frame, str):
                msg = json.loads(frame)
                if msg.get('op') == 'advertise':
                    subs = []
                    for ch in msg['channels']:
                        if only and ch['topic'] not in only:
                            continue
                        named[ch['id']] = ch['topic']
                        topics[len(topics) + 1] = ch['topic']
                        counts.setdefault(ch['topic'], [0, 0])
                        subs.append({'id': len(topics), 'channelId': ch['id']})
                    ws.send(json.dumps({'op': 'subscribe', 'subscriptions': subs}))
                elif msg.get('op') == 'status' and msg['message'].startswith(UNKNOWN):
                    # a channel created while we connected: foxglove-sdk knows it a moment later
                    cid = int(msg['message'][len(UNKNOWN):])
                    time.sleep(0.2)
                    topics[len(topics) + 1] = named[cid]
                    ws.send(json.dumps({'op': 'subscribe', 'subscriptions': [
                        {'id': len(topics), 'channelId': cid}]}))
            elif frame[0] == 0x01:
                (sub,) = struct.unpack_from('<I', frame, 1)
                c = counts.setdefault(topics[sub], [0, 0])
                c[0] += 1
                c[1] += len(frame) - 13
    return {t: (c[0], c[1]) for t, c in sorted(counts.items())}


def layout_topics() -> frozenset[str]:
    """The topics config/foxglove_layout.json shows (3D panels' topics, plotted paths)."""
    from pathlib import Path

    from clis_app.live.layout import shown_topics
    path = Path(__file__).resolve().parent.parent / 'config' / 'foxglove_layout.json'
    return shown_topics(json.loads(path.read_text()))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--port', type=int, default=8765)
    ap.add_argument('--seconds', type=float, default=60.0)
    ap.add_argument('--wait', type=float, default=120.0,
                    help='seconds to wait for the server to accept connections')
    ap.add_argument('--topics', default='', metavar='LIST',
                    help="comma-separated topics to subscribe to; '' = every channel; "
                         "'layout' = those config/foxglove_layout.json shows")
    args = ap.parse_args()
    only = frozenset(t for t in args.topics.split(',') if t)
    if args.topics == 'layout':
        only = layout_topics()
    got = watch(args.port, args.seconds, args.wait, only)
    total = sum(n for n, _ in got.values())
    size = sum(b for _, b in got.values())
    print(f'{len(got)} channels, {total} messages, {size / 1e6:.1f} MB: '
          + ', '.join(f'{t} {n}' for t, (n, _) in got.items()))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
