"""``ros2 run cr_bridge emulator`` (or ``python -m cr_bridge.emulator``): a Cyber Rodent on a wire.

Speaks the robot's wire protocol (src/cr_bridge/PROTOCOL.md) on a UDP port on the loopback or
on a pty pair (a symlink to the pty's device, as a USB serial adapter appears), with the cr_sim
core as its motors and sensors (:class:`cr_bridge.core.device.Device`). The bridge connects to
it exactly as to the robot::

    python -m cr_bridge.emulator --link udp://127.0.0.1:9750 --start A
    python -m cr_bridge.emulator --link pty:/tmp/cr_tty        # bridge: node.device:=/tmp/cr_tty

Its clock runs at ``--speed`` times wall time (1 = a real robot; faster for tests and short
learning runs: the bridge follows the device's clock). It is not a ROS node (no rclpy): the
robot is not one either. Ctrl-C stops it; it prints one status line every 10 s of device time
unless ``--quiet``.
"""

from __future__ import annotations

import argparse
import contextlib
import os
from pathlib import Path
import sys
import time

import numpy as np

from cr_bridge.core.device import Device, Faults
from cr_bridge.transport import LinkError, UdpLink

__all__ = ['main', 'PtyEnd', 'make_device']


class PtyEnd:
    """The device's end of a pty pair; the other end's path is symlinked at ``path``."""

    def __init__(self, path: str) -> None:
        import tty
        self.master, slave = os.openpty()
        tty.setraw(slave)
        self.slave_name = os.ttyname(slave)
        os.close(slave)
        os.set_blocking(self.master, False)
        self.path = Path(path)
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()
        self.path.symlink_to(self.slave_name)

    def read(self, timeout: float) -> bytes:
        import select
        ready, _, _ = select.select([self.master], [], [], max(0.0, timeout))
        if not ready:
            return b''
        try:
            return os.read(self.master, 4096)
        except (BlockingIOError, OSError):     # EIO: no one has the other end open
            time.sleep(min(timeout, 0.01))
            return b''

    def write(self, data: bytes) -> None:
        with contextlib.suppress(BlockingIOError, OSError):
            os.write(self.master, data)

    def close(self) -> None:
        with contextlib.suppress(OSError):
            os.close(self.master)
        with contextlib.suppress(FileNotFoundError):
            if self.path.is_symlink():
                self.path.unlink()


def make_device(seed: int, start: str, arena_file: str = '', faults: Faults | None = None,
                true_pose: bool = True, speed: float = 1.0) -> Device:
    """A device in ``arena_file`` standing at ``start`` (a start name or 'random')."""
    from cr_sim.core.arena import load_arena
    from cr_sim.core.sim import Simulator, load_sim_params
    params = load_sim_params(overrides={'episode.time_limit': 3600.0})
    sim = Simulator(load_arena(arena_file or None), params, np.random.default_rng([seed, 10]))
    sim.reset(start=start)
    return Device(sim, np.random.default_rng([seed, 11]), faults, true_pose=true_pose,
                  speed=speed)


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog='emulator', description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('--link', default='udp://127.0.0.1:9750',
                   help='udp://HOST:PORT (loopback) or pty:PATH (default %(default)s)')
    p.add_argument('--speed', type=float, default=1.0,
                   help='device time / wall time (1 = a real robot; default %(default)s)')
    p.add_argument('--seed', type=int, default=0, help='seed of the sensor noise and faults')
    p.add_argument('--start', default='A', help="where the robot stands: a start name of the "
                   "arena or 'random' (default %(default)s)")
    p.add_argument('--arena', default='', help='arena file (default config/arena.yaml)')
    p.add_argument('--drop', type=float, default=0.0, help='probability a frame is lost')
    p.add_argument('--corrupt', type=float, default=0.0,
                   help='probability a frame has one flipped bit')
    p.add_argument('--garbage', type=float, default=0.0,
                   help='probability garbage bytes precede a frame')
    p.add_argument('--no-true-pose', action='store_true',
                   help='send no TRUE_POSE frames (the bridge then dead-reckons odom)')
    p.add_argument('--allow-network', action='store_true',
                   help='allow a non-loopback UDP address')
    p.add_argument('--quiet', action='store_true')
    args = p.parse_args(argv)
    if not 0.01 <= args.speed <= 1000.0:
        p.error(f'--speed {args.speed}: must be in [0.01, 1000]')
    for name in ('drop', 'corrupt', 'garbage'):
        if not 0.0 <= getattr(args, name) <= 1.0:
            p.error(f'--{name}: a probability in [0, 1]')
    return args


def main(argv: list[str] | None = None) -> int:
    # `ros2 run` passes --ros-args ...: not ours
    argv = list(sys.argv[1:] if argv is None else argv)
    if '--ros-args' in argv:
        argv = argv[:argv.index('--ros-args')]
    args = parse_args(argv)
    try:
        device = make_device(args.seed, args.start, args.arena,
                             Faults(args.drop, args.corrupt, args.garbage),
                             true_pose=not args.no_true_pose, speed=args.speed)
    except (ValueError, OSError) as exc:
        print(f'emulator: {exc}', file=sys.stderr)
        return 2
    try:
        if args.link.startswith('pty:'):
            link = PtyEnd(args.link[4:])
            where = f'{link.path} -> {link.slave_name}'
        else:
            link = UdpLink(args.link, allow_network=args.allow_network, listen=True)
            where = args.link
    except (LinkError, ValueError, OSError) as exc:
        print(f'emulator: {exc}', file=sys.stderr)
        return 2
    print(f'emulator: listening on {where}, speed x{args.speed:g}, start {args.start}',
          flush=True)
    period = device.dt / args.speed
    next_wall = time.monotonic()
    next_report = 10.0
    try:
        while True:
            now = time.monotonic()
            while now < next_wall:
                device.receive(link.read(next_wall - now))
                now = time.monotonic()
            device.receive(link.read(0.0))
            for frame in device.tick():
                try:
                    link.write(frame)
                except LinkError:
                    pass                       # nobody listening: a robot talks anyway
            next_wall += period
            if now - next_wall > 1.0:
                next_wall = now                # fell far behind: no burst
            if not args.quiet and device.t >= next_report:
                next_report += 10.0
                x, y, th = device.sim.pose
                print(f'emulator: t {device.t:.1f} s, pose ({x:.2f}, {y:.2f}, {th:.2f}), '
                      f'commands {len(device.commands)}, parser {device.parser.stats.as_dict()}',
                      flush=True)
                device.commands.clear()
    except KeyboardInterrupt:
        pass
    finally:
        link.close()
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
