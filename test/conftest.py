"""Test-session setup: DDS on loopback only, and a ROS_DOMAIN_ID of this session's own.

Applied at import time so that every process a test starts inherits it (graph tests use real
rclpy and Fast DDS in separate OS processes).
"""

from __future__ import annotations

import os
from pathlib import Path

from clis_learner.ros_env import apply_ros_env, pick_domain_id
import pytest

REPO = Path(__file__).resolve().parent.parent
os.environ.pop('ROS_DOMAIN_ID', None)
apply_ros_env(domain_id=pick_domain_id())
os.environ.setdefault('CLIS_CONFIG_DIR', str(REPO / 'config'))


def pytest_report_header(config):
    return (f'ROS_DOMAIN_ID={os.environ["ROS_DOMAIN_ID"]} '
            f'FASTRTPS_DEFAULT_PROFILES_FILE={os.environ.get("FASTRTPS_DEFAULT_PROFILES_FILE")}')


@pytest.fixture(scope='session')
def repo() -> Path:
    """The repository root."""
    return REPO


@pytest.fixture(scope='session')
def install_dir() -> Path:
    """The colcon install/ folder (made by `make setup`)."""
    path = REPO / 'install'
    if not (path / 'setup.bash').is_file():
        pytest.fail('no colcon install/: run the tests through `make test` (it builds first)')
    return path


def pytest_collection_modifyitems(config, items):
    """With ``pytest -n N --dist loadgroup`` (pytest-xdist; ``make test``), the tests that
    share a module-scoped fixture (one process graph, one run) go to one worker, so that it is
    made once; the others are spread one by one. A parametrized module fixture makes one group
    per value (test_robot_contract: the simulator's half and the bridge's on two workers)."""
    for item in items:
        info = getattr(item, '_fixtureinfo', None)
        if info is None:
            continue
        params = getattr(getattr(item, 'callspec', None), 'params', {})
        shared = []
        for name in item.fixturenames:
            defs = info.name2fixturedefs.get(name)
            if defs and defs[-1].scope in ('module', 'class', 'package'):
                shared.append(f'{name}={params[name]}' if name in params else name)
        if shared:
            key = item.module.__name__ + ''.join(f'[{s}]' for s in sorted(shared)
                                                  if '=' in s)
            item.add_marker(pytest.mark.xdist_group(key))
