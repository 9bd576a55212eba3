"""cr_bridge links without ROS: the emulator's pty pair through pyserial, unplugged and plugged
in again; UDP stays on the loopback."""

from __future__ import annotations

import time

from cr_bridge.core import protocol as proto
from cr_bridge.emulator import PtyEnd, make_device
from cr_bridge.transport import LinkError, open_link
import pytest


def pump(device, end, link, parser, seconds):
    """Run the device for ``seconds`` of wall time, 1 tick per 10 ms; frames the host got."""
    got, sent = [], 0
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        device.receive(end.read(0.0))
        for raw in device.tick():
            end.write(raw)
            sent += 1
        got += parser.feed(link.read(0.01))
    got += parser.feed(link.read(0.05))
    return got, sent


def test_pty_serial_link_carries_frames_both_ways_and_survives_unplugging(tmp_path):
    path = str(tmp_path / 'cr_tty')
    device = make_device(0, 'A')
    end = PtyEnd(path)
    link = open_link(path)
    parser = proto.FrameParser()
    link.write(proto.encode(proto.WheelCommand(0.2, 0.2, 1.0), 0))
    got, sent = pump(device, end, link, parser, 0.5)
    sensors = [f.payload for f in got if f.type is proto.MsgType.SENSORS]
    assert len(got) == sent > 20, 'every frame the device wrote arrived'
    assert sensors[1].wheels == pytest.approx((0.2, 0.2)), 'the command went the other way'
    # unplugged: the host sees the hang-up as a LinkError, not as garbage or silence
    end.close()
    with pytest.raises(LinkError):
        for _ in range(50):
            link.read(0.02)
    link.close()
    with pytest.raises(LinkError):
        open_link(path)                   # nothing there until the device is back
    # plugged in again (a new pty, as a USB adapter re-enumerates): a new link and parser,
    # the device's numbering goes on, nothing is lost after the reconnect
    end = PtyEnd(path)
    link = open_link(path)
    parser = proto.FrameParser()
    try:
        got, sent = pump(device, end, link, parser, 0.5)
        assert len(got) == sent > 20
        assert parser.stats.lost == 0 and parser.stats.malformed == 0
    finally:
        link.close()
        end.close()


def test_udp_links_refuse_addresses_off_the_loopback():
    with pytest.raises(LinkError, match='loopback'):
        open_link('udp://192.0.2.1:9750')
    with pytest.raises(LinkError, match='loopback'):
        open_link('socket://192.0.2.1:9750')
    with pytest.raises(ValueError, match='udp://HOST:PORT'):
        open_link('udp://127.0.0.1')
    open_link('udp://127.0.0.1:9').close()


def test_the_listening_end_answers_whoever_wrote_last():
    """The emulator's end of a UDP link answers the bridge's newest socket: a bridge that
    reopened its link (new socket, new port) after a timeout is heard and answered; the old
    socket gets nothing more."""
    import socket as _socket

    from cr_bridge.transport import UdpLink
    with _socket.socket(_socket.AF_INET, _socket.SOCK_DGRAM) as s:
        s.bind(('127.0.0.1', 0))
        port = s.getsockname()[1]
    device = UdpLink(f'udp://127.0.0.1:{port}', listen=True)
    first, second = (open_link(f'udp://127.0.0.1:{port}') for _ in range(2))
    try:
        first.write(b'hello 1')
        assert device.read(1.0) == b'hello 1'
        device.write(b'frame 1')
        assert first.read(1.0) == b'frame 1'
        second.write(b'hello 2')                       # the bridge reopened its link
        assert device.read(1.0) == b'hello 2'
        device.write(b'frame 2')
        assert second.read(1.0) == b'frame 2'
        assert first.read(0.2) == b''                  # the closed one gets nothing more
    finally:
        for link in (device, first, second):
            link.close()
