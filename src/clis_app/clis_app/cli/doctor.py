"""``clis doctor``: what ROS/DDS setup is in force, and whether two processes can talk.

The check starts two separate OS processes (``python -m clis_app.cli.doctor talker`` and
``... listener``) that exchange ``std_msgs/String`` over real rclpy and Fast DDS, in the
environment ``clis`` configured (loopback-only profile, own ROS_DOMAIN_ID).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time

TOPIC = 'clis_doctor'


def _talker(timeout: float) -> int:
    import rclpy
    from std_msgs.msg import String

    rclpy.init()
    node = rclpy.create_node('clis_doctor_talker')
    pub = node.create_publisher(String, TOPIC, 10)
    deadline = time.monotonic() + timeout
    k = 0
    try:
        while time.monotonic() < deadline:
            pub.publish(String(data=f'ping {k} from pid {os.getpid()}'))
            k += 1
            rclpy.spin_once(node, timeout_sec=0.05)
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


def _listener(timeout: float, want: int) -> int:
    import rclpy
    from std_msgs.msg import String

    rclpy.init()
    node = rclpy.create_node('clis_doctor_listener')
    got: list[str] = []
    node.create_subscription(String, TOPIC, lambda m: got.append(m.data), 10)
    deadline = time.monotonic() + timeout
    try:
        while time.monotonic() < deadline and len(got) < want:
            rclpy.spin_once(node, timeout_sec=0.05)
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    print(f'received {len(got)}' + (f': {got[0]!r}' if got else ''), flush=True)
    return 0 if len(got) >= want else 1


def exchange(env: dict[str, str] | None = None, timeout: float = 20.0,
             want: int = 5) -> tuple[bool, str, float]:
    """Run a talker and a listener as two processes; True if ``want`` messages arrived.

    Returns
    -------
    ok : bool
    output : str
        What the listener printed (and the talker's stderr on failure).
    seconds : float
        Wall time until the listener had its messages.
    """
    env = dict(os.environ if env is None else env)
    cmd = [sys.executable, '-m', 'clis_app.cli.doctor']
    t0 = time.monotonic()
    talker = subprocess.Popen(cmd + ['talker', '--timeout', str(timeout + 5)], env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        listener = subprocess.run(cmd + ['listener', '--timeout', str(timeout),
                                         '--want', str(want)],
                                  env=env, capture_output=True, text=True, timeout=timeout + 30)
    finally:
        talker.terminate()
        try:
            _, talker_err = talker.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            talker.kill()
            _, talker_err = talker.communicate()
    seconds = time.monotonic() - t0
    out = (listener.stdout + listener.stderr).strip()
    if listener.returncode != 0:
        out += '\n' + (talker_err or '').strip()
    return listener.returncode == 0, out, seconds


def run_doctor() -> int:
    """Print the setup in force and the result of the two-process exchange."""
    from clis_app.graph.ros_env import describe

    print('clis doctor')
    for key, value in describe().items():
        print(f'  {key:30s} {value}')
    try:
        import rclpy
        print(f'  {"rclpy":30s} {os.path.dirname(rclpy.__file__)}')
        from rclpy.utilities import get_rmw_implementation_identifier
        print(f'  {"rmw in use":30s} {get_rmw_implementation_identifier()}')
    except ImportError as exc:
        print(f'doctor: FAIL: rclpy cannot be imported ({exc}); run `make setup` and '
              '`source env.sh`')
        return 1
    ok, out, seconds = exchange()
    print(f'  {"two-process pub/sub":30s} {"ok" if ok else "FAILED"} in {seconds:.1f} s '
          f'({out.splitlines()[0] if out else "no output"})')
    if not ok:
        print(out)
        print('doctor: FAIL: a listener process did not hear a talker process. Check that no '
              'other FASTRTPS_DEFAULT_PROFILES_FILE is set and that /dev/shm is writable.')
        return 1
    print('doctor: PASS')
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description='Two-process DDS probe used by clis doctor.')
    parser.add_argument('role', choices=('talker', 'listener'))
    parser.add_argument('--timeout', type=float, default=20.0)
    parser.add_argument('--want', type=int, default=5)
    args = parser.parse_args(argv)
    if args.role == 'talker':
        return _talker(args.timeout)
    return _listener(args.timeout, args.want)


if __name__ == '__main__':
    raise SystemExit(main())
