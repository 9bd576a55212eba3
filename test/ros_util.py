"""Helpers for graph tests: real rclpy in the test process, nodes as separate OS processes."""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable
import functools
import re
import shutil
import subprocess
import sys
import time

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile


def start_node(module: str, *ros_args: str) -> subprocess.Popen:
    """``python -m module --ros-args ...`` as a child process (inherits the test DDS env)."""
    cmd = [sys.executable, '-m', module]
    if ros_args:
        cmd += ['--ros-args', *ros_args]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def stop(proc: subprocess.Popen, timeout: float = 10.0) -> str:
    """Interrupt a node process; return what it printed."""
    if proc.poll() is None:
        proc.send_signal(2)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
    out, _ = proc.communicate()
    return out or ''


# A network namespace of the processes under test only (``unshare -rn``: no privileges): the
# loopback, and one veth interface x0 with a default route and the multicast route, so that
# anything these processes send off the loopback leaves through x0 and is counted there. Other
# traffic of the host is not in the count. IPv6 is off in it (the kernel's own router
# solicitations and MLD reports would count otherwise).
NETNS_SCRIPT = r"""
set -e
ip link set lo up
ip link add x0 type veth peer name x1
echo 1 > /proc/sys/net/ipv6/conf/all/disable_ipv6
echo 1 > /proc/sys/net/ipv6/conf/default/disable_ipv6
ip addr add 10.199.0.2/24 dev x0
ip link set x1 up
ip link set x0 up
ip route add default via 10.199.0.1 dev x0
ip route add 224.0.0.0/4 dev x0
set +e
tx() { awk '$1 == "x0:" {print $11}' /proc/net/dev; }
before=$(tx)
"$@"
rc=$?
echo "NETNS_TX_PACKETS $(( $(tx) - before ))"
exit $rc
"""


@functools.cache
def netns_available() -> bool:
    """Whether this host lets an unprivileged user make a network namespace with a veth."""
    if not (shutil.which('unshare') and shutil.which('ip')):
        return False
    out = subprocess.run(['unshare', '-rn', 'sh', '-c', NETNS_SCRIPT, 'netns', 'true'],
                         capture_output=True, text=True)
    return out.returncode == 0 and 'NETNS_TX_PACKETS' in out.stdout


def in_netns(argv: list[str]) -> list[str]:
    """``argv`` run in a network namespace of its own (NETNS_SCRIPT); its output ends with
    the packets its processes sent off the loopback (:func:`netns_tx_packets`)."""
    return ['unshare', '-rn', 'sh', '-c', NETNS_SCRIPT, 'netns', *argv]


def netns_tx_packets(output: str) -> int:
    """The packets sent off the loopback, from the output of an :func:`in_netns` command."""
    found = re.findall(r'^NETNS_TX_PACKETS (-?\d+)$', output, re.MULTILINE)
    assert found, f'no packet count in the output:\n{output[-2000:]}'
    return int(found[-1])


def assert_grid(stamps: list[float], seqs: list[int], step: float, topic: str,
                tol: float = 1e-6) -> None:
    """The publisher's grid, judged on what arrived whatever the probe lost: two messages
    with consecutive publication sequence numbers are ``step`` [s of their clock] apart.

    The rate of arrival at a Python probe (~1,400 msg/s at x10) is the reader's, not the
    node's, so it is not judged."""
    pairs = [b - a for (a, qa), (b, qb) in zip(zip(stamps, seqs), zip(stamps[1:], seqs[1:]))
             if qb == qa + 1]
    assert len(pairs) >= 10, f'{topic}: {len(pairs)} consecutive pairs of {len(stamps)}'
    bad = [d for d in pairs if abs(d - step) > tol]
    assert not bad, f'{topic}: steps {bad[:5]} off the {step} s grid'
    assert all(b > a for a, b in zip(seqs, seqs[1:])), f'{topic}: out of order'


class Probe:
    """A test-side node in its own context that records what arrives on given topics."""

    def __init__(self, name: str = 'probe') -> None:
        self.context = Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.msgs: dict[str, list] = defaultdict(list)
        # publication sequence number of each message in msgs (DDS numbers a publisher's
        # messages 1, 2, ...): a missing number is a message this probe did not receive
        self.seqs: dict[str, list[int]] = defaultdict(list)

    def listen(self, msg_type, topic: str, latched: bool = False, depth: int = 100) -> None:
        qos = QoSProfile(depth=depth, durability=DurabilityPolicy.TRANSIENT_LOCAL if latched
                         else DurabilityPolicy.VOLATILE)

        def take(msg, info, topic=topic) -> None:
            self.msgs[topic].append(msg)
            self.seqs[topic].append(info['publication_sequence_number'])
        self.node.create_subscription(msg_type, topic, take, qos)

    def spin_until(self, done: Callable[[], bool], timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.02)
            if done():
                return True
        return False

    def spin_once(self, timeout: float = 0.02) -> None:
        """Serve what arrived (waiting at most ``timeout`` s for it)."""
        self.executor.spin_once(timeout_sec=timeout)

    def spin_for(self, seconds: float) -> None:
        self.spin_until(lambda: False, seconds)

    def drain(self, quiet: float = 1.0, timeout: float = 60.0) -> bool:
        """Take what is queued: spin until nothing has arrived for ``quiet`` seconds.

        Samples stay in a reader's queue after their publisher has gone, so a probe that lags
        a fast graph still gets them once the graph has stopped, if its queue held them all.
        """
        seen = {'n': -1, 'at': time.monotonic()}

        def still() -> bool:
            n = sum(len(v) for v in self.msgs.values())
            if n != seen['n']:
                seen['n'], seen['at'] = n, time.monotonic()
            return time.monotonic() - seen['at'] >= quiet
        return self.spin_until(still, timeout)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)
