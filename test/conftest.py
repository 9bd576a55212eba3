"""Test-session setup: DDS on loopback only, and a ROS_DOMAIN_ID of this session's own.

Applied at import time so that every process a test starts inherits it (graph tests use real
rclpy and Fast DDS in separate OS processes).

The test process itself observes the graph as the recorder does: its probes load
``config/fastdds_recorder.xml`` (UDP on 127.0.0.1 with a 4 MiB receive buffer). On the loopback
profile a probe waiting for a core on a loaded host lost packets from the kernel's default
208 KiB buffer; a reliable stream stalls at such a loss until it is repaired, and a run that
ends first leaves the probe without the rest (with six busy loops on two cores, a run's
cmd_vel up to 76.8 s of 240 s, its wheels with holes).
"""

from __future__ import annotations

import os
from pathlib import Path

from clis_learner.ros_env import (
    PROFILE_VAR,
    RECORDER_PROFILE_NAME,
    apply_ros_env,
    pick_domain_id,
    use_profile,
)
import pytest
import rclpy
from rclpy.context import Context

REPO = Path(__file__).resolve().parent.parent
os.environ.pop('ROS_DOMAIN_ID', None)
apply_ros_env(domain_id=pick_domain_id())
os.environ.setdefault('CLIS_CONFIG_DIR', str(REPO / 'config'))


def _observe_as_the_recorder() -> None:
    """Load the recorder's profile for this process's participants; children keep the
    loopback profile. Fast DDS reads the profiles file once, at a process's first participant:
    one is made (and dropped) here, under the recorder's profile, before any test runs."""
    children = os.environ[PROFILE_VAR]
    use_profile(RECORDER_PROFILE_NAME)
    context = Context()
    try:
        rclpy.init(context=context)
        rclpy.create_node('conftest_profile', context=context).destroy_node()
    finally:
        rclpy.try_shutdown(context=context)
        os.environ[PROFILE_VAR] = children


_observe_as_the_recorder()


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
