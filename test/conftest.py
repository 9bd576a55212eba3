"""Setup of a test run: DDS on loopback only, and a ROS_DOMAIN_ID that no other run holds.

Applied at import time so that every process a test starts inherits it (graph tests use real
rclpy and Fast DDS in separate OS processes).
"""

from __future__ import annotations

import functools
import os
from pathlib import Path
import re

from clis_app.graph.ros_env import apply_ros_env, pick_domain_id
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


@functools.cache
def _module_fixtures(path: str) -> str | None:
    """Whether the test file ``path`` (relative to the repository) has a module-scoped
    fixture: None, 'module', or 'params' (a parametrized one)."""
    try:
        text = (REPO / path).read_text()
    except OSError:
        return None
    if re.search(r"scope='module',\s*params=", text):
        return 'params'
    return 'module' if "scope='module'" in text else None


@pytest.hookimpl(tryfirst=True)
def pytest_xdist_make_scheduler(config, log):
    """``pytest -n N --dist loadscope`` (pytest-xdist; ``make test``): the tests of a file
    that has a module-scoped fixture (one process graph, one run) go to one worker, so that it
    is made once, one group per value of a parametrized one (test_robot_contract: the
    simulator's half and the bridge's on two workers); every other test is spread alone."""
    if config.getvalue('dist') != 'loadscope':
        return None
    from xdist.scheduler import LoadScopeScheduling

    class SharedFixtureScheduling(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            path, _, name = nodeid.partition('::')
            kind = _module_fixtures(path)
            if kind is None:
                return nodeid
            if kind == 'params' and name.endswith(']'):
                return f'{path}[{name.rsplit("[", 1)[1]}'
            return path
    return SharedFixtureScheduling(config, log)
