"""The DDS environment every process of the project starts with: loopback only by default.

docs/design.md §8: with the Fast DDS profile ``config/fastdds_loopback.xml`` (loaded through
``FASTRTPS_DEFAULT_PROFILES_FILE``) and ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``, nodes send
nothing on non-loopback interfaces. Each run picks its own ``ROS_DOMAIN_ID`` (unless one is
set) so parallel runs on one machine don't cross-talk. Talking to a robot on another machine is
an explicit opt-in (``network=True``, i.e. ``clis --network``) or the user's own profile.

This module must be used *before* rclpy is imported in the process it configures (or to build
the environment of child processes); it imports no ROS.
"""

from __future__ import annotations

from collections.abc import MutableMapping
import fcntl
import os
from pathlib import Path
import secrets
import tempfile

from clis_base.params import config_dir

PROFILE_VAR = 'FASTRTPS_DEFAULT_PROFILES_FILE'
PROFILE_NAME = 'fastdds_loopback.xml'
#: The graph's variant (shared memory carries the user data): ``clis run`` loads it
GRAPH_PROFILE_NAME = 'fastdds_graph.xml'
#: The recorder's variant (UDP loopback with a large receive buffer)
RECORDER_PROFILE_NAME = 'fastdds_recorder.xml'
OUR_PROFILES = (PROFILE_NAME, GRAPH_PROFILE_NAME, RECORDER_PROFILE_NAME)
#: Fast DDS maps domain d to UDP ports 7400 + 250 d (+ offsets); ids above ~100 collide with
#: Linux ephemeral ports, so runs draw from this range.
DOMAIN_RANGE = (1, 100)


def loopback_profile() -> Path:
    """Path of the project's loopback-only Fast DDS profile."""
    return config_dir() / PROFILE_NAME


#: Held for the life of the process: the domain id it claimed (see :func:`pick_domain_id`).
_claimed: dict[int, int] = {}


def lock_path(domain_id: int) -> Path:
    """The lock file by which a process of the project claims ``domain_id`` on this machine."""
    return Path(tempfile.gettempdir()) / f'clis-ros-domain-{domain_id}.lock'


def pick_domain_id() -> int:
    """A ROS_DOMAIN_ID in :data:`DOMAIN_RANGE` for one run (or one test session) that no other
    process of the project on this machine holds: tried in random order, claimed with an
    exclusive ``flock`` on :func:`lock_path` that lasts as long as this process (its children
    inherit the id through the environment). Falls back to a random id if all are taken."""
    lo, hi = DOMAIN_RANGE
    ids = list(range(lo, hi + 1))
    secrets.SystemRandom().shuffle(ids)
    for domain_id in ids:
        try:
            fd = os.open(lock_path(domain_id), os.O_RDWR | os.O_CREAT, 0o666)
        except OSError:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            continue
        os.write(fd, f'{os.getpid()}\n'.encode())
        _claimed[domain_id] = fd
        return domain_id
    return ids[0]


def apply_ros_env(env: MutableMapping[str, str] | None = None, *, network: bool = False,
                  domain_id: int | None = None) -> MutableMapping[str, str]:
    """Set the DDS variables in ``env`` (default: ``os.environ``) and return it.

    Parameters
    ----------
    env : mapping, optional
        Environment to modify in place (``os.environ`` if None).
    network : bool
        Opt in to other machines: do not load the loopback profile and do not restrict
        discovery to localhost. A profile the user set is always kept.
    domain_id : int, optional
        Force this ROS_DOMAIN_ID; otherwise keep the one set, or pick a random one.
    """
    env = os.environ if env is None else env
    if domain_id is not None:
        env['ROS_DOMAIN_ID'] = str(int(domain_id))
    elif not env.get('ROS_DOMAIN_ID'):
        env['ROS_DOMAIN_ID'] = str(pick_domain_id())
    if network:
        if Path(env.get(PROFILE_VAR, '')).name in OUR_PROFILES:   # any of ours: loopback
            del env[PROFILE_VAR]
        if env.get('ROS_AUTOMATIC_DISCOVERY_RANGE') == 'LOCALHOST':
            del env['ROS_AUTOMATIC_DISCOVERY_RANGE']
        env.pop('CLIS_LOOPBACK', None)
        return env
    env.setdefault(PROFILE_VAR, str(loopback_profile()))
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env['CLIS_LOOPBACK'] = '1'
    return env


def use_profile(name: str, env: MutableMapping[str, str] | None = None
                ) -> MutableMapping[str, str]:
    """Load the project's profile ``config/NAME`` instead of the project's profile in force
    (one of :data:`OUR_PROFILES`; the same loopback-only rules in each); a profile of the
    user's own (or none, ``--network``) is kept. Returns ``env`` (default ``os.environ``)."""
    env = os.environ if env is None else env
    current = env.get(PROFILE_VAR, '')
    if Path(current).name in OUR_PROFILES:
        ours = Path(current).with_name(name)
        if ours.is_file():
            env[PROFILE_VAR] = str(ours)
    return env


def use_graph_profile(env: MutableMapping[str, str] | None = None) -> MutableMapping[str, str]:
    """For the CLIS graph's nodes (``clis run``): ``config/fastdds_graph.xml``, shared memory
    carrying the user data between the graph's processes (:func:`use_profile`)."""
    return use_profile(GRAPH_PROFILE_NAME, env)


def describe(env: MutableMapping[str, str] | None = None) -> dict[str, str]:
    """What is in force, for ``clis doctor`` and run headers."""
    env = os.environ if env is None else env
    profile = env.get(PROFILE_VAR, '')
    return {
        'ROS_DISTRO': env.get('ROS_DISTRO', 'jazzy (PyPI wheels)'),
        'RMW_IMPLEMENTATION': env.get('RMW_IMPLEMENTATION', '(default)'),
        'ROS_DOMAIN_ID': env.get('ROS_DOMAIN_ID', '0 (unset)'),
        'ROS_AUTOMATIC_DISCOVERY_RANGE': env.get('ROS_AUTOMATIC_DISCOVERY_RANGE', '(default)'),
        'DDS profile': profile or '(none: Fast DDS defaults, all interfaces)',
        'scope': ('loopback only' if profile.endswith((PROFILE_NAME, GRAPH_PROFILE_NAME))
                  else 'network (opted in or user profile)'),
    }
