"""Workspace foundation: packages installed where `ros2 run` looks, real DDS, loopback only."""

from __future__ import annotations

import ast
import os
from pathlib import Path
import subprocess
import sys
import xml.etree.ElementTree as ET

from clis_app.cli.doctor import exchange
from clis_app.graph.ros_env import PROFILE_VAR, apply_ros_env, loopback_profile
import pytest
from ros_util import in_netns, netns_available, netns_tx_packets

PACKAGES = ('clis_modules', 'clis_learner', 'clis_app', 'cr_bridge', 'cr_sim', 'clis_base')


def console_scripts(setup_py: Path) -> list[str]:
    """Executable names declared in a setup.py's ``console_scripts`` (parsed, not run)."""
    tree = ast.parse(setup_py.read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Dict):
            for key, value in zip(node.keys, node.values):
                if isinstance(key, ast.Constant) and key.value == 'console_scripts':
                    return [ast.literal_eval(e).split('=')[0].strip() for e in value.elts]
    return []


def test_console_scripts_parser_reads_declared_names(tmp_path):
    setup = tmp_path / 'setup.py'
    setup.write_text("setup(entry_points={'console_scripts': ['a = p.m:main', 'b=p.n:main']})")
    assert console_scripts(setup) == ['a', 'b']


@pytest.mark.parametrize('pkg', PACKAGES)
def test_package_manifest_is_format3_ament_python(repo, pkg):
    root = ET.parse(repo / 'src' / pkg / 'package.xml').getroot()
    assert root.get('format') == '3'
    assert root.findtext('name') == pkg
    assert root.find('export/build_type').text == 'ament_python'
    assert (repo / 'src' / pkg / 'resource' / pkg).is_file()


@pytest.mark.parametrize('pkg', PACKAGES)
def test_console_scripts_installed_where_ros2_run_looks(repo, install_dir, pkg):
    from ament_index_python.packages import get_package_prefix

    prefix = Path(get_package_prefix(pkg))
    assert prefix.resolve() == (install_dir / pkg).resolve()
    for exe in console_scripts(repo / 'src' / pkg / 'setup.py'):
        path = prefix / 'lib' / pkg / exe
        assert path.is_file(), f'{pkg}/{exe} is not installed at {path}'
        assert os.access(path, os.X_OK), f'{path} is not executable'


def test_every_declared_script_answers_help(repo, install_dir):
    # all at once (each mostly imports): the suite's workers wait for one, not for each
    procs = {(pkg, exe): subprocess.Popen([str(install_dir / pkg / 'lib' / pkg / exe), '--help'],
                                          stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                          stdin=subprocess.DEVNULL, text=True)
             for pkg in PACKAGES for exe in console_scripts(repo / 'src' / pkg / 'setup.py')}
    for (pkg, exe), proc in procs.items():
        out, err = proc.communicate(timeout=120)
        assert proc.returncode == 0, f'{pkg}/{exe} --help failed: {err}'
        assert 'usage' in out.lower()


def test_clis_is_on_path_after_sourcing_the_install(repo, install_dir):
    out = subprocess.run(['bash', '-c', f'source {repo}/env.sh && command -v clis'],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0
    assert out.stdout.strip().startswith(str(install_dir))


def test_apply_ros_env_loopback_by_default_and_network_is_opt_in():
    env: dict[str, str] = {}
    apply_ros_env(env)
    assert env[PROFILE_VAR].endswith('fastdds_loopback.xml')
    assert Path(env[PROFILE_VAR]).is_file()
    assert env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
    assert 1 <= int(env['ROS_DOMAIN_ID']) <= 100
    apply_ros_env(env, network=True)
    assert PROFILE_VAR not in env and 'ROS_AUTOMATIC_DISCOVERY_RANGE' not in env
    # the graph's and the recorder's profiles are loopback-only too: dropped as well (a test
    # process that had run `clis run` in-process kept the graph's, and its "network" control
    # sent nothing off the loopback)
    for name in ('fastdds_graph.xml', 'fastdds_recorder.xml'):
        env = {PROFILE_VAR: str(Path(loopback_profile()).with_name(name))}
        apply_ros_env(env, network=True)
        assert PROFILE_VAR not in env, name
    user = {PROFILE_VAR: '/etc/my_profile.xml', 'ROS_DOMAIN_ID': '42'}
    apply_ros_env(user, network=True)
    assert user[PROFILE_VAR] == '/etc/my_profile.xml' and user['ROS_DOMAIN_ID'] == '42'


@pytest.mark.ros
def test_two_processes_exchange_messages_over_fast_dds():
    ok, out, seconds = exchange(timeout=20, want=10)
    assert ok, out
    assert 'received 10' in out


@pytest.mark.ros
@pytest.mark.skipif(not netns_available(), reason='needs unshare -rn (user network namespaces)')
@pytest.mark.parametrize('network', [False, True])
def test_default_dds_sends_nothing_off_loopback(network):
    """A talker and a listener in a network namespace of their own, where the only way off
    the loopback is one counted interface: the default (loopback) profile sends nothing
    through it, whatever else the host sends; ``network=True`` (no profile) does, which shows
    the count sees DDS traffic."""
    code = ('from clis_app.cli.doctor import exchange\n'
            'from clis_app.graph.ros_env import apply_ros_env\n'
            f'apply_ros_env(network={network})\n'
            'ok, out, _ = exchange(timeout=30, want=20)\n'
            'print(out)\n'
            'raise SystemExit(0 if ok else 1)\n')
    out = subprocess.run(in_netns([sys.executable, '-c', code]), capture_output=True,
                         text=True, timeout=180)
    assert out.returncode == 0, out.stdout + out.stderr
    assert 'received 20' in out.stdout, out.stdout
    sent = netns_tx_packets(out.stdout)
    if network:
        assert sent > 0, 'DDS without the profile sends discovery off the loopback'
    else:
        assert sent == 0, f'{sent} packets off the loopback with the default profile'


@pytest.mark.ros
def test_clis_doctor_passes(repo):
    out = subprocess.run([sys.executable, '-m', 'clis_app.cli', 'doctor'],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr
    assert 'doctor: PASS' in out.stdout
    assert 'loopback only' in out.stdout


def test_picked_domain_ids_are_exclusive_while_held():
    from clis_app.graph.ros_env import DOMAIN_RANGE, lock_path, pick_domain_id
    a, b = pick_domain_id(), pick_domain_id()
    assert a != b and all(DOMAIN_RANGE[0] <= d <= DOMAIN_RANGE[1] for d in (a, b))
    # another process cannot claim them while this one lives
    probe = ('import fcntl, os, sys; fd = os.open(sys.argv[1], os.O_RDWR); '
             'fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)')
    for d in (a, b):
        out = subprocess.run([sys.executable, '-c', probe, str(lock_path(d))],
                             capture_output=True, text=True)
        assert out.returncode != 0 and 'BlockingIOError' in out.stderr
