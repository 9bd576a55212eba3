"""Start the robot interface for tests: the simulator node, or the bridge + device emulator."""

from __future__ import annotations

import random
import socket
import subprocess
import sys

from ros_util import start_node, stop

EMULATOR = 'cr_bridge.emulator'


def free_udp_port() -> int:
    """A free UDP port below the kernel's ephemeral range (32768-60999), drawn at random.

    An ephemeral port (bind to 0) can be handed to another socket (the bridge's own) between
    this check and the emulator's bind: 'Address already in use' was seen once. Fast DDS
    binds a few ports per domain in 7400-32650 and skips to others when one is taken."""
    rng = random.Random()
    for _ in range(200):
        port = rng.randrange(20000, 30000)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            try:
                s.bind(('127.0.0.1', port))
            except OSError:
                continue
            return port
    raise RuntimeError('no free UDP port in 20000-29999')


def start_emulator(port: int, speed: float, *extra: str) -> subprocess.Popen:
    """``python -m cr_bridge.emulator`` on udp://127.0.0.1:PORT."""
    return subprocess.Popen([sys.executable, '-m', EMULATOR, '--link',
                             f'udp://127.0.0.1:{port}', '--speed', str(speed), '--quiet',
                             *extra], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)


class Robot:
    """The processes behind one robot interface; ``kind`` = 'sim' or 'bridge'."""

    def __init__(self, kind: str, speed: float, *ros_args: str, start: str = 'A',
                 emulator_args: tuple[str, ...] = ()) -> None:
        self.kind = kind
        self.procs: list[subprocess.Popen] = []
        if kind == 'sim':
            self.procs.append(start_node('cr_sim.sim_node', '-p', f'node.speed_factor:={speed}',
                                         '-p', f'node.start:={start}', *ros_args))
        else:
            self.port = free_udp_port()
            self.speed = speed
            self.emulator_args = emulator_args
            self.start_emulator(start)
            self.procs.append(start_node('cr_bridge.bridge_node', '-p',
                                         f'node.device:=udp://127.0.0.1:{self.port}',
                                         '-p', 'node.start:=here', *ros_args))

    def start_emulator(self, start: str = 'A') -> None:
        self.emulator = start_emulator(self.port, self.speed, '--start', start,
                                       *self.emulator_args)
        self.procs.insert(0, self.emulator)

    def stop_emulator(self) -> str:
        self.procs.remove(self.emulator)
        return stop(self.emulator)

    def close(self) -> str:
        return '\n'.join(stop(p) for p in reversed(self.procs))
