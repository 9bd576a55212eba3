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
