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
