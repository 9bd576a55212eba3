"""cr_bridge wire protocol: round trips, the safety of the encoder, and a fuzzed parser.

The parser must never crash on any input, never yield a frame whose CRC does not check, always
reject a frame with any single corrupted byte (CRC-16 detects every burst of <= 16 bits), find
every intact frame again after garbage, and count what it dropped.
"""

from __future__ import annotations

import math
import os
import struct

from cr_bridge.core import protocol as proto
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
import pytest

#: cases per fuzzed property in a run of the suite (each run draws new ones, and hypothesis
#: replays a failing case from its database first); CLIS_FUZZ_EXAMPLES=1500 for a deep run
#: (7,500 cases, about 2 CPU-minutes)
EXAMPLES = int(os.environ.get('CLIS_FUZZ_EXAMPLES', '300'))
FUZZ = settings(max_examples=EXAMPLES, deadline=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

finite = st.floats(-1.3, 1.3, allow_nan=False)
sensor_frames = st.builds(
    proto.SensorFrame,
    t=st.integers(0, 2**32 - 1).map(lambda ms: ms / 1000.0),
    ir=st.lists(st.floats(0.0, 0.5), min_size=7, max_size=7).map(tuple),
    bearings=st.lists(st.one_of(st.just(math.nan), st.floats(-3.14, 3.14)), min_size=5,
                      max_size=5).map(tuple),
    distances=st.lists(st.one_of(st.just(math.nan), st.floats(0.0, 5.0)), min_size=5,
                       max_size=5).map(tuple),
    wheels=st.tuples(finite, finite),
    bump=st.integers(0, 255),
    accel=st.tuples(*[st.floats(-100.0, 100.0)] * 3))
payloads = st.one_of(
    st.builds(proto.WheelCommand, finite, finite, st.floats(0.0, 2.0)),
    sensor_frames,
    st.builds(proto.Heartbeat, st.integers(0, 2**32 - 1).map(lambda ms: ms / 1000.0),
              st.integers(0, 255)),
    st.builds(proto.DeviceError, st.integers(1, 8), st.integers(0, 255),
              st.integers(0, 65535)),
    st.builds(proto.TruePose, st.integers(0, 2**32 - 1).map(lambda ms: ms / 1000.0),
              st.floats(-2.0, 2.0), st.floats(-2.0, 2.0), st.floats(-3.14, 3.14)))


def stream(items: list) -> tuple[bytes, list[bytes]]:
    frames = [proto.encode(p, k) for k, p in enumerate(items)]
    return b''.join(frames), frames


def parse_in_chunks(data: bytes, cuts: list[int], parser: proto.FrameParser | None = None):
    parser = parser or proto.FrameParser()
    out, last = [], 0
    for c in sorted({min(max(c, 0), len(data)) for c in cuts} | {len(data)}):
        out += parser.feed(data[last:c])
        last = c
    return out, parser


def crc_ok(raw: bytes) -> bool:
    return struct.unpack('<H', raw[-2:])[0] == proto.crc16(raw[2:-2])


def test_crc_is_ccitt_false_and_frames_have_the_documented_layout():
    assert proto.crc16(b'123456789') == 0x29B1
    raw = proto.encode(proto.WheelCommand(0.25, -1.3, 0.3), 513)
    assert raw[:2] == proto.SYNC and raw[2] == proto.PROTOCOL_VERSION and raw[3] == 0x01
    assert struct.unpack('<HH', raw[4:8]) == (513, 6)
    assert struct.unpack('<hhH', raw[8:14]) == (250, -1300, 300)
    assert crc_ok(raw) and len(raw) == 16


@FUZZ
@given(st.lists(payloads, min_size=1, max_size=12), st.lists(st.integers(0, 2000), max_size=8))
def test_round_trip_in_any_chunking(items, cuts):
    data, frames = stream(items)
    got, parser = parse_in_chunks(data, cuts)
    assert [f.raw for f in got] == frames
    assert [f.seq for f in got] == list(range(len(items)))
    assert parser.stats.malformed == 0 and parser.stats.skipped_bytes == 0
    for f, p in zip(got, items):
        assert f.payload == proto.decode_payload(f.type, proto.encode_payload(p)[1])
        if isinstance(p, proto.WheelCommand):
            assert f.payload.v_left == pytest.approx(p.v_left, abs=5e-4)
        if isinstance(p, proto.SensorFrame):
            for a, b in zip(f.payload.bearings, p.bearings):
                assert (math.isnan(a) and math.isnan(b)) or a == pytest.approx(b, abs=1e-4)


@settings(max_examples=EXAMPLES, deadline=None)
@given(st.sampled_from([math.nan, math.inf, -math.inf]), finite, st.booleans())
def test_a_non_finite_wheel_command_cannot_be_encoded(bad, good, left):
    cmd = proto.WheelCommand(bad, good) if left else proto.WheelCommand(good, bad)
    with pytest.raises(proto.ProtocolError, match='not finite'):
        proto.encode(cmd, 0)


@FUZZ
@given(st.binary(max_size=600), st.lists(st.integers(0, 600), max_size=6))
def test_garbage_never_crashes_and_yields_no_frame_with_a_bad_crc(garbage, cuts):
    got, parser = parse_in_chunks(garbage, cuts)
    assert all(crc_ok(f.raw) for f in got)
    s = parser.stats
    assert s.frames == len(got)
    assert min(s.as_dict().values()) >= 0


@FUZZ
@given(st.lists(payloads, min_size=1, max_size=6), st.data())
def test_any_single_corrupted_byte_is_rejected_and_the_rest_recovered(items, data):
    raw, frames = stream(items)
    k = data.draw(st.integers(0, len(raw) - 1), label='position')
    value = data.draw(st.integers(0, 255).filter(lambda v: v != raw[k]), label='value')
    bad = raw[:k] + bytes([value]) + raw[k + 1:]
    hit = next(i for i, f in enumerate(frames) if k < sum(map(len, frames[:i + 1])))
    # the line goes on (heartbeats): a corrupted byte that forged a sync with a plausible
    # header of another version makes the parser read up to MAX_PAYLOAD bytes before it
    # resyncs -- a delay, never a lost frame
    tail = [proto.encode(proto.Heartbeat(0.0), len(items) + j) for j in range(30)]
    got, parser = parse_in_chunks(bad + b''.join(tail),
                                  data.draw(st.lists(st.integers(0, len(raw)), max_size=4)))
    raws = [f.raw for f in got]
    assert frames[hit] not in raws, 'the corrupted frame was accepted'
    # every other frame is found again (a corrupted header may cost the parser a resync
    # through the following bytes, never a frame)
    expected = [f for i, f in enumerate(frames) if i != hit]
    assert raws[:len(expected)] == expected
    assert parser.stats.malformed + parser.stats.skipped_bytes > 0


@FUZZ
@given(st.lists(payloads, min_size=1, max_size=8),
       st.lists(st.tuples(st.integers(0, 10_000), st.binary(min_size=1, max_size=40)),
                max_size=6), st.lists(st.integers(0, 3000), max_size=6))
def test_frames_between_garbage_are_all_found(items, junk, cuts):
    raw, frames = stream(items)
    bounds = [0]
    for f in frames:
        bounds.append(bounds[-1] + len(f))
    pieces, last = [], 0
    for pos, blob in sorted((bounds[p % len(bounds)], b) for p, b in junk):
        pieces += [raw[last:pos], blob]
        last = pos
    pieces.append(raw[last:])
    # the line goes on: garbage that forged a plausible header of another version makes the
    # parser read up to MAX_PAYLOAD bytes past it before resyncing (a delay, not a loss)
    pieces += [proto.encode(proto.Heartbeat(0.0), len(items) + j) for j in range(30)]
    got, _ = parse_in_chunks(b''.join(pieces), cuts)
    raws = [f.raw for f in got]
    assert all(crc_ok(r) for r in raws)
    assert [r for r in raws if r in frames] == frames, 'an intact frame was lost to garbage'


@FUZZ
@given(st.binary(min_size=1, max_size=300), st.lists(payloads, min_size=1, max_size=4),
       st.lists(st.integers(0, 1000), max_size=4))
def test_mutated_streams_never_crash_and_only_checked_frames_pass(noise, items, cuts):
    raw, _ = stream(items)
    mixed = bytearray(raw)
    for i, b in enumerate(noise):                  # overwrite, insert and delete bytes
        p = (i * 7919 + b) % (len(mixed) + 1)
        if b % 3 == 0:
            mixed.insert(p, b)
        elif b % 3 == 1 and p < len(mixed):
            mixed[p] = b
        elif p < len(mixed):
            del mixed[p]
    got, _ = parse_in_chunks(bytes(mixed), cuts)
    assert all(crc_ok(f.raw) for f in got)


def test_every_single_bit_flip_of_every_frame_type_is_rejected():
    for payload in (proto.WheelCommand(0.3, 0.2), proto.Heartbeat(1.0, 1),
                    proto.DeviceError(6, 0, 9), proto.TruePose(2.0, 0.1, -0.2, 1.0),
                    proto.SensorFrame(3.0, (0.1,) * 7, (0.2,) * 5, (1.0,) * 5, (0.1, 0.2))):
        raw = proto.encode(payload, 7)
        for bit in range(8 * len(raw)):
            bad = bytearray(raw)
            bad[bit // 8] ^= 1 << (bit % 8)
            assert proto.FrameParser().feed(bytes(bad)) == [], (payload, bit)


def test_bad_version_unknown_type_and_bad_length_are_counted_and_dropped():
    good = proto.encode(proto.Heartbeat(1.0), 1)
    other_version = proto.encode_frame(0x03, 2, good[8:-2], version=2)
    unknown = proto.encode_frame(0x7E, 3, b'abc')
    bad_length = proto.encode_frame(0x01, 4, b'\x00' * 5)      # WHEELS needs 6
    tail = proto.encode(proto.Heartbeat(2.0), 5)
    p = proto.FrameParser()
    got = p.feed(good + other_version + unknown + bad_length + tail)
    assert [f.seq for f in got] == [1, 5]
    assert p.stats.bad_version == 1 and p.stats.unknown_type == 1
    assert p.stats.bad_length >= 1 and p.stats.lost == 3


def test_sequence_duplicates_and_old_frames_are_dropped_gaps_counted_reboot_resynced():
    hb = proto.Heartbeat(0.0)
    p = proto.FrameParser(resync_after=3)
    seqs = [65534, 65535, 0, 0, 65535, 3, 10]       # wrap, duplicate, old, gaps
    got = p.feed(b''.join(proto.encode(hb, s) for s in seqs))
    assert [f.seq for f in got] == [65534, 65535, 0, 3, 10]
    assert p.stats.out_of_sequence == 2 and p.stats.lost == 2 + 6
    # a device that rebooted numbers from 0 again: after 3 drops it is followed
    got = p.feed(b''.join(proto.encode(hb, s) for s in range(6)))
    assert [f.seq for f in got] == [3, 4, 5]
