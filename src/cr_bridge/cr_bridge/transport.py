"""Byte links to the robot: a serial line (pyserial: a tty, a pty, ``socket://``...) or UDP.

A link URL names the device:

* ``udp://HOST:PORT`` -- datagrams to a device listening on HOST:PORT; this end binds an
  ephemeral port on the same host. HOST must be a loopback address (127.0.0.0/8, ::1)
  unless ``allow_network`` is set: the project sends nothing off this machine by default.
* anything else -- a pyserial URL (``serial.serial_for_url``): a device path such as
  ``/dev/ttyUSB0`` or the emulator's pty symlink, ``socket://127.0.0.1:PORT``, ``loop://``.

Every link is non-blocking from the caller's side: :meth:`Link.read` waits at most its
timeout and returns the bytes that arrived (``b''`` if none); a broken link raises
:class:`LinkError` (the bridge then stops the robot and reconnects with backoff).
"""

from __future__ import annotations

import ipaddress
import select
import socket
from urllib.parse import urlsplit

__all__ = ['LinkError', 'Link', 'UdpLink', 'SerialLink', 'open_link', 'parse_udp', 'is_loopback']


#: Receive buffer of a UDP link [bytes] (SO_RCVBUFFORCE where allowed, else capped by the
#: system's rmem_max).
RCVBUF = 4 * 1024 * 1024


class LinkError(OSError):
    """The link is down (cannot open, read or write)."""


def is_loopback(host: str) -> bool:
    """Whether ``host`` (a name or an address) resolves to loopback addresses only."""
    try:
        infos = socket.getaddrinfo(host, None)
    except socket.gaierror:
        return False
    return bool(infos) and all(ipaddress.ip_address(info[4][0]).is_loopback for info in infos)


def parse_udp(url: str) -> tuple[str, int]:
    """``udp://HOST:PORT`` -> ``(host, port)``; ValueError if malformed."""
    parts = urlsplit(url)
    if parts.scheme != 'udp' or not parts.hostname or parts.port is None:
        raise ValueError(f'{url!r}: expected udp://HOST:PORT')
    return parts.hostname, parts.port


class Link:
    """A byte link (interface)."""

    url: str

    def read(self, timeout: float) -> bytes:
        raise NotImplementedError

    def write(self, data: bytes) -> None:
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError


class UdpLink(Link):
    """Datagrams with one peer (``udp://HOST:PORT``); ``bind`` = this end's own port
    (0 = ephemeral) -- the emulator binds the device's port and answers whoever wrote last."""

    def __init__(self, url: str, allow_network: bool = False, listen: bool = False) -> None:
        host, port = parse_udp(url)
        if not allow_network and not is_loopback(host):
            raise LinkError(f'{url}: not a loopback address; set allow_network to talk to '
                            'another machine')
        self.url = url
        self.listen = listen
        family = socket.AF_INET6 if ':' in host else socket.AF_INET
        self.sock = socket.socket(family, socket.SOCK_DGRAM)
        self.sock.setblocking(False)
        # a few seconds of frames: a reader the machine starves for a moment loses none
        for opt in (getattr(socket, 'SO_RCVBUFFORCE', None), socket.SO_RCVBUF):
            if opt is None:
                continue
            try:
                self.sock.setsockopt(socket.SOL_SOCKET, opt, RCVBUF)
                break
            except OSError:
                continue
        try:
            if listen:
                self.sock.bind((host, port))
                self.peer = None
            else:
                self.sock.bind((host, 0))
                self.peer = (host, port)
        except OSError as exc:
            self.sock.close()
            raise LinkError(f'{url}: {exc}') from exc

    def read(self, timeout: float) -> bytes:
        chunks = []
        try:
            ready, _, _ = select.select([self.sock], [], [], max(0.0, timeout))
            while ready:
                data, addr = self.sock.recvfrom(2048)
                if self.listen and addr != self.peer:
                    # a listening end answers whoever wrote last: a bridge that reopened its
                    # link (a new socket, a new port) is heard, and the frames go to it, not
                    # to the closed one (the emulator kept its first peer, and a bridge that
                    # had timed out once before the device's first frame never connected)
                    self.peer = addr
                    chunks.clear()
                if addr == self.peer:
                    chunks.append(data)
                ready, _, _ = select.select([self.sock], [], [], 0.0)
        except BlockingIOError:
            pass
        except OSError as exc:   # e.g. ICMP port unreachable: the device is not there
            if chunks:
                return b''.join(chunks)
            raise LinkError(f'{self.url}: {exc}') from exc
        return b''.join(chunks)

    def write(self, data: bytes) -> None:
        if self.peer is None:
            return                      # a listening end answers once someone wrote
        try:
            self.sock.sendto(data, self.peer)
        except OSError as exc:
            raise LinkError(f'{self.url}: {exc}') from exc

    def close(self) -> None:
        self.sock.close()


class SerialLink(Link):
    """A pyserial port (``serial.serial_for_url``), raw, non-blocking reads."""

    def __init__(self, url: str, baudrate: int = 115200) -> None:
        import serial
        self.url = url
        try:
            self.port = serial.serial_for_url(url, baudrate=baudrate, timeout=0,
                                              write_timeout=0.5, exclusive=None)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise LinkError(f'{url}: {exc}') from exc
        self._serial_error = serial.SerialException

    def read(self, timeout: float) -> bytes:
        try:
            fd = self.port.fileno()
        except Exception:                 # noqa: BLE001 - URL handlers without a fd (loop://)
            fd = None
        try:
            if fd is not None:
                ready, _, _ = select.select([fd], [], [], max(0.0, timeout))
                if not ready:
                    return b''
                n = self.port.in_waiting
                data = self.port.read(max(n, 1))
                if not data:
                    # readable but nothing: the other end hung up (pty closed)
                    raise LinkError(f'{self.url}: the device hung up')
                return data
            return self.port.read(self.port.in_waiting or 1)
        except (self._serial_error, OSError) as exc:
            raise LinkError(f'{self.url}: {exc}') from exc

    def write(self, data: bytes) -> None:
        try:
            self.port.write(data)
        except (self._serial_error, OSError) as exc:
            raise LinkError(f'{self.url}: {exc}') from exc

    def close(self) -> None:
        try:
            self.port.close()
        except Exception:                 # noqa: BLE001 - closing a dead port
            pass


def open_link(url: str, allow_network: bool = False, baudrate: int = 115200) -> Link:
    """The link of a URL (module docstring). Raises LinkError if it cannot be opened."""
    if url.startswith('udp://'):
        return UdpLink(url, allow_network=allow_network)
    if url.startswith('socket://') and not allow_network:
        host = urlsplit(url).hostname or ''
        if not is_loopback(host):
            raise LinkError(f'{url}: not a loopback address; set allow_network')
    return SerialLink(url, baudrate)
