"""The Cyber Rodent wire protocol: framed binary messages, encoder and streaming parser.

Pure Python (no ROS, no I/O): the bridge node, the device emulator and the tests share it.
The byte layout is documented in ``src/cr_bridge/PROTOCOL.md``; in short, every frame is::

    offset  size  field
    0       2     sync         0xC5 0x52
    2       1     version      PROTOCOL_VERSION (1)
    3       1     type         a MsgType
    4       2     seq          uint16, per sender, +1 per frame, wraps at 65536
    6       2     length       payload bytes (<= MAX_PAYLOAD)
    8       N     payload      little endian, layout per type
    8+N     2     crc          CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF) of bytes 2..8+N

Physical quantities are fixed-point integers (mm, mm/s, 1e-4 rad, ms): a NaN or an infinity
cannot be represented, so :func:`encode_wheels` refuses them (the bridge never sends one).

:class:`FrameParser` takes bytes in any chunks (a serial line or UDP datagrams), resynchronises
on the sync bytes after garbage, and yields only frames whose CRC, version, type and payload
length are all right; everything else is counted and dropped (:class:`ParserStats`). Sequence
numbers: a duplicate or older frame is counted (``out_of_sequence``) and dropped; a gap is
counted as ``lost`` and the frame is kept.
"""

from __future__ import annotations

import binascii
from dataclasses import dataclass, field
import enum
import math
import struct

__all__ = [
    'SYNC', 'PROTOCOL_VERSION', 'MAX_PAYLOAD', 'HEADER', 'MsgType', 'ErrorCode', 'Frame',
    'WheelCommand', 'SensorFrame', 'Heartbeat', 'DeviceError', 'TruePose', 'ProtocolError',
    'ParserStats', 'FrameParser', 'encode_frame', 'encode', 'decode_payload', 'crc16',
    'encode_wheels', 'NOT_SEEN', 'NO_RANGE',
]

SYNC = b'\xc5\x52'
PROTOCOL_VERSION = 1
MAX_PAYLOAD = 255
HEADER = struct.Struct('<2sBBHH')          # sync, version, type, seq, length
_CRC = struct.Struct('<H')
FRAME_OVERHEAD = HEADER.size + _CRC.size  # 10 bytes

#: Fixed-point sentinels: a bearing of a blob not seen; a blob distance not measured.
NOT_SEEN = -32768
NO_RANGE = 0xFFFF
#: Fixed-point scales.
MM = 1000.0          # m -> mm
BEARING = 10000.0    # rad -> 1e-4 rad
ACCEL = 100.0        # m/s^2 -> cm/s^2


class ProtocolError(ValueError):
    """A value that cannot be put on the wire (non-finite, out of range, malformed)."""


class MsgType(enum.IntEnum):
    """Frame types (direction: host = the bridge, device = the robot or the emulator)."""

    WHEELS = 0x01      # host -> device: wheel velocity command
    SENSORS = 0x02     # device -> host: one sensor frame per control tick
    HEARTBEAT = 0x03   # both ways: link alive, status flags
    ERROR = 0x04       # both ways: what went wrong
    TRUE_POSE = 0x05   # device -> host, optional: external tracking (emulator, motion capture)


class ErrorCode(enum.IntEnum):
    """Codes of an ERROR frame."""

    BAD_CRC = 1
    BAD_VERSION = 2
    UNKNOWN_TYPE = 3
    BAD_LENGTH = 4
    OUT_OF_SEQUENCE = 5
    WATCHDOG_STOP = 6      # device: no wheel command within its timeout, motors stopped
    OUT_OF_RANGE = 7       # device: a command beyond the motor limit (clamped)
    MOTOR_FAULT = 8


@dataclass(frozen=True)
class WheelCommand:
    """``WHEELS`` payload ``<hhH``: wheel velocities [m/s] and the device-side timeout [s]
    after which the device stops on its own if no newer command arrives."""

    v_left: float
    v_right: float
    timeout: float = 0.5


@dataclass(frozen=True)
class SensorFrame:
    """``SENSORS`` payload: everything the robot senses at device time ``t``.

    Layout ``<IBB`` (t_ms, n_ir, n_blob), ``n_ir x H`` IR [mm], ``n_blob x hH`` (bearing
    [1e-4 rad] or NOT_SEEN, distance [mm] or NO_RANGE), ``hh`` executed wheels [mm/s],
    ``B`` bump bits (bit 0 = any contact), ``hhh`` accelerometer [cm/s^2].

    Attributes
    ----------
    t : float
        Device time [s] (ms resolution).
    ir : tuple of float, shape (n_ir,)
        IR readings, distance from the body surface [m].
    bearings : tuple of float, shape (n_blob,)
        Blob bearings relative to the heading [rad]; NaN = not seen. Blob 0 is the
        destination, then the landmarks in arena order.
    distances : tuple of float, shape (n_blob,)
        Camera range estimate of each blob [m]; NaN = none.
    wheels : tuple of float, shape (2,)
        Executed (v_left, v_right) [m/s] from the wheel encoders.
    bump : int
        Bump switch bits (0 = no contact).
    accel : tuple of float, shape (3,)
        Body-frame acceleration [m/s^2].
    """

    t: float
    ir: tuple[float, ...]
    bearings: tuple[float, ...]
    distances: tuple[float, ...]
    wheels: tuple[float, float]
    bump: int = 0
    accel: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Heartbeat:
    """``HEARTBEAT`` payload ``<IB``: sender time [s] (ms resolution), status bits
    (device: bit 0 motors enabled, bit 1 its watchdog stopped the motors)."""

    t: float
    status: int = 0


@dataclass(frozen=True)
class DeviceError:
    """``ERROR`` payload ``<BBH``: code, detail byte, seq of the offending frame."""

    code: int
    detail: int = 0
    ref_seq: int = 0


@dataclass(frozen=True)
class TruePose:
    """``TRUE_POSE`` payload ``<Iiih``: device time, x, y [mm], heading [1e-4 rad]."""

    t: float
    x: float
    y: float
    theta: float


Payload = WheelCommand | SensorFrame | Heartbeat | DeviceError | TruePose


@dataclass(frozen=True)
class Frame:
    """A frame the parser accepted: its sequence number, decoded payload and its bytes."""

    type: MsgType
    seq: int
    payload: Payload
    raw: bytes = field(default=b'', repr=False, compare=False)


def crc16(data: bytes | bytearray | memoryview) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no final xor);
    ``crc16(b'123456789') == 0x29B1``."""
    return binascii.crc_hqx(data, 0xFFFF)


# ---------------------------------------------------------------------------- payloads

def _fixed(value: float, scale: float, lo: int, hi: int, what: str) -> int:
    v = float(value)
    if not math.isfinite(v):
        raise ProtocolError(f'{what} = {value!r} is not finite')
    n = round(v * scale)
    if not lo <= n <= hi:
        raise ProtocolError(f'{what} = {value!r} is out of the wire range '
                            f'[{lo / scale}, {hi / scale}]')
    return n


def _clip_fixed(value: float, scale: float, lo: int, hi: int) -> int:
    """Saturating fixed point for sensor values (a device never fails to report)."""
    return max(lo, min(hi, round(float(value) * scale)))


def encode_wheels(cmd: WheelCommand) -> bytes:
    """``WHEELS`` payload. Raises ProtocolError for a non-finite or out-of-range value, so a
    NaN can never reach a motor."""
    return struct.pack('<hhH', _fixed(cmd.v_left, MM, -32767, 32767, 'v_left'),
                       _fixed(cmd.v_right, MM, -32767, 32767, 'v_right'),
                       _fixed(cmd.timeout, MM, 0, 65535, 'timeout'))


def _encode_sensors(s: SensorFrame) -> bytes:
    if len(s.bearings) != len(s.distances):
        raise ProtocolError('a sensor frame needs one distance per bearing')
    if len(s.ir) > 32 or len(s.bearings) > 16:
        raise ProtocolError('at most 32 IR beams and 16 blobs')
    if not math.isfinite(s.t) or s.t < 0:
        raise ProtocolError(f'device time {s.t!r} must be finite and >= 0')
    parts = [struct.pack('<IBB', round(s.t * 1000.0) % 2**32, len(s.ir), len(s.bearings))]
    parts.append(struct.pack(f'<{len(s.ir)}H', *(
        NO_RANGE - 1 if not math.isfinite(r) else _clip_fixed(r, MM, 0, NO_RANGE - 1)
        for r in s.ir)))
    for b, d in zip(s.bearings, s.distances):
        bb = NOT_SEEN if not math.isfinite(b) else _clip_fixed(
            math.remainder(b, 2 * math.pi), BEARING, -31416, 31416)
        dd = NO_RANGE if not math.isfinite(d) else _clip_fixed(d, MM, 0, NO_RANGE - 1)
        parts.append(struct.pack('<hH', bb, dd))
    wheels = [0 if not math.isfinite(v) else _clip_fixed(v, MM, -32767, 32767)
              for v in s.wheels]
    accel = [0 if not math.isfinite(a) else _clip_fixed(a, ACCEL, -32767, 32767)
             for a in s.accel]
    parts.append(struct.pack('<hhBhhh', *wheels, int(s.bump) & 0xFF, *accel))
    return b''.join(parts)


def _decode_sensors(p: bytes) -> SensorFrame:
    t_ms, n_ir, n_blob = struct.unpack_from('<IBB', p, 0)
    if len(p) != _sensor_length(n_ir, n_blob):
        raise ProtocolError('sensor payload length does not match its counts')
    off = 6
    ir = tuple(v / MM for v in struct.unpack_from(f'<{n_ir}H', p, off))
    off += 2 * n_ir
    bearings, distances = [], []
    for _ in range(n_blob):
        b, d = struct.unpack_from('<hH', p, off)
        off += 4
        bearings.append(math.nan if b == NOT_SEEN else b / BEARING)
        distances.append(math.nan if d == NO_RANGE else d / MM)
    vl, vr, bump, ax, ay, az = struct.unpack_from('<hhBhhh', p, off)
    return SensorFrame(t_ms / 1000.0, ir, tuple(bearings), tuple(distances),
                       (vl / MM, vr / MM), bump, (ax / ACCEL, ay / ACCEL, az / ACCEL))


def _sensor_length(n_ir: int, n_blob: int) -> int:
    return 6 + 2 * n_ir + 4 * n_blob + 11


_FIXED_LENGTH = {MsgType.WHEELS: 6, MsgType.HEARTBEAT: 5, MsgType.ERROR: 4,
                 MsgType.TRUE_POSE: 14}


def encode_payload(payload: Payload) -> tuple[MsgType, bytes]:
    """``(type, payload bytes)`` of a payload object."""
    if isinstance(payload, WheelCommand):
        return MsgType.WHEELS, encode_wheels(payload)
    if isinstance(payload, SensorFrame):
        return MsgType.SENSORS, _encode_sensors(payload)
    if isinstance(payload, Heartbeat):
        return MsgType.HEARTBEAT, struct.pack('<IB', round(payload.t * 1000.0) % 2**32,
                                              int(payload.status) & 0xFF)
    if isinstance(payload, DeviceError):
        return MsgType.ERROR, struct.pack('<BBH', int(payload.code) & 0xFF,
                                          int(payload.detail) & 0xFF,
                                          int(payload.ref_seq) & 0xFFFF)
    if isinstance(payload, TruePose):
        return MsgType.TRUE_POSE, struct.pack(
            '<Iiih', round(payload.t * 1000.0) % 2**32,
            _fixed(payload.x, MM, -2**31, 2**31 - 1, 'x'),
            _fixed(payload.y, MM, -2**31, 2**31 - 1, 'y'),
            _clip_fixed(math.remainder(payload.theta, 2 * math.pi), BEARING, -31416, 31416))
    raise ProtocolError(f'cannot encode {type(payload).__name__}')


def decode_payload(mtype: int, p: bytes) -> Payload:
    """The payload object of a frame of type ``mtype``. Raises ProtocolError if the payload
    length is wrong for the type, or the type is unknown."""
    try:
        t = MsgType(mtype)
    except ValueError:
        raise ProtocolError(f'unknown frame type 0x{mtype:02x}') from None
    if t is MsgType.SENSORS:
        if len(p) < 6:
            raise ProtocolError('sensor payload too short')
        return _decode_sensors(p)
    if len(p) != _FIXED_LENGTH[t]:
        raise ProtocolError(f'{t.name} payload of {len(p)} bytes, expected {_FIXED_LENGTH[t]}')
    if t is MsgType.WHEELS:
        vl, vr, to = struct.unpack('<hhH', p)
        return WheelCommand(vl / MM, vr / MM, to / MM)
    if t is MsgType.HEARTBEAT:
        ms, status = struct.unpack('<IB', p)
        return Heartbeat(ms / 1000.0, status)
    if t is MsgType.ERROR:
        return DeviceError(*struct.unpack('<BBH', p))
    ms, x, y, th = struct.unpack('<Iiih', p)
    return TruePose(ms / 1000.0, x / MM, y / MM, th / BEARING)


def encode_frame(mtype: int, seq: int, payload: bytes, version: int = PROTOCOL_VERSION) -> bytes:
    """One frame around raw payload bytes (any type/version: the tests forge bad ones)."""
    if len(payload) > MAX_PAYLOAD:
        raise ProtocolError(f'payload of {len(payload)} bytes > {MAX_PAYLOAD}')
    body = HEADER.pack(SYNC, version & 0xFF, mtype & 0xFF, seq & 0xFFFF, len(payload)) + payload
    return body + _CRC.pack(crc16(memoryview(body)[2:]))


def encode(payload: Payload, seq: int) -> bytes:
    """One frame of a payload object with sequence number ``seq`` (taken mod 2^16)."""
    mtype, data = encode_payload(payload)
    return encode_frame(mtype, seq, data)


# ---------------------------------------------------------------------------- parser

@dataclass
class ParserStats:
    """What the parser dropped (all counters only grow).

    Attributes
    ----------
    frames : int
        Frames accepted.
    bad_crc, bad_version, unknown_type, bad_length : int
        Frames dropped for that reason (``bad_length``: a header whose length is impossible
        for its type, or a payload that does not decode).
    skipped_bytes : int
        Bytes discarded while looking for a sync (garbage, or the start of a bad frame).
    out_of_sequence : int
        Duplicate or older frames, dropped.
    lost : int
        Frames missing in the sequence (gaps), as seen from the next frame.
    """

    frames: int = 0
    bad_crc: int = 0
    bad_version: int = 0
    unknown_type: int = 0
    bad_length: int = 0
    skipped_bytes: int = 0
    out_of_sequence: int = 0
    lost: int = 0

    @property
    def malformed(self) -> int:
        """Frames dropped as malformed (CRC, version, type, length)."""
        return self.bad_crc + self.bad_version + self.unknown_type + self.bad_length

    def as_dict(self) -> dict[str, int]:
        return {**{k: getattr(self, k) for k in self.__dataclass_fields__},
                'malformed': self.malformed}


@dataclass
class FrameParser:
    """Streaming parser with resynchronisation and sequence checking (module docstring).

    Parameters
    ----------
    accept : set of MsgType, optional
        Types this end accepts (others are counted as ``unknown_type``); default all.
    resync_after : int
        After this many consecutive out-of-sequence frames the peer is taken to have
        restarted its numbering (e.g. a device reboot) and the next frame is accepted.
    """

    accept: frozenset = frozenset(MsgType)
    resync_after: int = 8
    stats: ParserStats = field(default_factory=ParserStats)

    def __post_init__(self) -> None:
        self._buf = bytearray()
        self._last_seq: int | None = None
        self._old_run = 0

    def reset_sequence(self) -> None:
        """Forget the last sequence number (a new connection) and any partial frame."""
        self._last_seq = None
        self._old_run = 0
        self._buf.clear()

    def feed(self, data: bytes | bytearray | memoryview) -> list[Frame]:
        """Frames completed by ``data`` (possibly none), in order."""
        buf = self._buf
        buf += data
        out: list[Frame] = []
        st = self.stats
        pos = 0
        n = len(buf)
        while True:
            k = buf.find(SYNC, pos)
            if k < 0:
                # keep a last byte that may be the first half of a sync
                keep = 1 if n > pos and buf[n - 1] == SYNC[0] else 0
                st.skipped_bytes += n - pos - keep
                pos = n - keep
                break
            st.skipped_bytes += k - pos
            pos = k
            if n - pos < HEADER.size:
                break
            _, version, mtype, seq, length = HEADER.unpack_from(buf, pos)
            if (mtype == MsgType.SENSORS and version == PROTOCOL_VERSION
                    and n - pos < HEADER.size + 6 and length >= 6):
                break                          # wait for the counts that fix its length
            if length > MAX_PAYLOAD or not self._plausible(buf, pos, version, mtype, length):
                st.bad_length += 1 if version == PROTOCOL_VERSION and mtype in self.accept \
                    else 0
                st.skipped_bytes += 1
                pos += 1                       # not a frame start: look for the next sync
                continue
            end = pos + HEADER.size + length + _CRC.size
            if end > n:
                break                          # wait for the rest
            (crc,) = _CRC.unpack_from(buf, end - _CRC.size)
            if crc != crc16(memoryview(buf)[pos + 2:end - _CRC.size]):
                st.bad_crc += 1
                st.skipped_bytes += 1
                pos += 1                       # the length may be garbage: resync byte-wise
                continue
            payload = bytes(buf[pos + HEADER.size:end - _CRC.size])
            start, pos = pos, end          # a good CRC: its length is true
            if version != PROTOCOL_VERSION:
                st.bad_version += 1
                continue
            if mtype not in self.accept:
                st.unknown_type += 1
                continue
            try:
                obj = decode_payload(mtype, payload)
            except (ProtocolError, struct.error):
                st.bad_length += 1
                continue
            if not self._in_sequence(seq):
                continue
            st.frames += 1
            out.append(Frame(MsgType(mtype), seq, obj, bytes(buf[start:end])))
        del buf[:pos]
        return out

    @staticmethod
    def _plausible(buf: bytearray, pos: int, version: int, mtype: int, length: int) -> bool:
        """Header check before waiting for the payload: a known type of this version must
        have its length (fixed, or for SENSORS the one its counts give), so that a corrupted
        length does not stall the stream. Other versions and types are read whole (at most
        MAX_PAYLOAD bytes), to be counted once their CRC checks."""
        if version != PROTOCOL_VERSION or mtype not in _KNOWN:
            return True
        if mtype == MsgType.SENSORS:
            if length < 6:
                return False
            n_ir, n_blob = buf[pos + HEADER.size + 4], buf[pos + HEADER.size + 5]
            return length == _sensor_length(n_ir, n_blob)
        return length == _FIXED_LENGTH[MsgType(mtype)]

    def _in_sequence(self, seq: int) -> bool:
        st = self.stats
        if self._last_seq is not None:
            d = (seq - self._last_seq) & 0xFFFF
            if d == 0 or d >= 0x8000:
                self._old_run += 1
                if self._old_run <= self.resync_after:
                    st.out_of_sequence += 1
                    return False
            else:
                st.lost += d - 1
        self._old_run = 0
        self._last_seq = seq
        return True


_KNOWN = frozenset(int(t) for t in MsgType)
