"""Node parameters, checked once for every node (clis_base.ros.ros_params, docs/design.md).

Each node's installed console script (what ``ros2 run PKG EXE`` runs) is started as a real
process: a key no node declares stops it with exit code 2 and one line naming the nearest known
key; a value of the wrong type stops it with one line naming the key, the type and the range; an
integer for a float is taken as that float (read back through the node's parameter service).
"""

from __future__ import annotations

from pathlib import Path
import subprocess

import pytest
from rcl_interfaces.msg import ParameterType
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter_client import AsyncParameterClient
from ros_util import stop

#: node name -> (package, executable, a float key of its own, its allowed range as printed)
NODES = {
    'sim': ('cr_sim', 'sim', 'node.speed_factor', '[0.0, 1000.0]'),
    'innate': ('clis_modules', 'innate', 'module.params_timeout', '[0.0, 600.0]'),
    'view': ('clis_modules', 'view', 'module.resend_period', None),
    'place': ('clis_modules', 'place', 'module.params_timeout', '[0.0, 600.0]'),
    'arbiter': ('clis_modules', 'arbiter', 'arbiter_node.lockstep_timeout', None),
    'learner': ('clis_learner', 'learner', 'learner_node.close_timeout', None),
    'recorder': ('clis_app', 'recorder', 'recorder.flush_interval', None),
    'bridge': ('cr_bridge', 'bridge', 'node.link_timeout', '[0.05, 30.0]'),
}


def exe(install_dir: Path, name: str) -> str:
    package, executable, _, _ = NODES[name]
    return str(install_dir / package / 'lib' / package / executable)


def start(install_dir: Path, name: str, cwd: Path, *params: str) -> subprocess.Popen:
    args = [exe(install_dir, name), '--ros-args']
    for p in params:
        args += ['-p', p]
    if name == 'recorder':
        args += ['-p', f'recorder.path:={cwd / "bag"}']
    return subprocess.Popen(args, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            stdin=subprocess.DEVNULL, text=True)


def bad_lines(out: str) -> list[str]:
    return [s for s in out.splitlines() if s.strip()]


def finish_all(procs: dict[str, subprocess.Popen]) -> dict[str, tuple[int, str]]:
    """Each node's exit code and output; a node still running after 120 s (a hang guard) fails
    the test, and none is left running."""
    result = {}
    try:
        for name, proc in procs.items():
            out, _ = proc.communicate(timeout=120)
            result[name] = (proc.returncode, out)
    finally:
        for proc in procs.values():
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
    return result


def test_every_node_rejects_an_unknown_key_naming_the_nearest(install_dir, tmp_path):
    typo = {'sim': ('node.sped_factor:=5.0', 'node.speed_factor'),
            'bridge': ('node.linktimeout:=1.0', 'node.link_timeout'),
            'learner': ('learner_node.close_timout:=1.0', 'learner_node.close_timeout'),
            'recorder': ('recorder.flush_intervall:=1.0', 'recorder.flush_interval'),
            'arbiter': ('arbiter_node.lockstep_timout:=1.0', 'arbiter_node.lockstep_timeout'),
            'innate': ('common.bta:=2.0', 'common.beta'),
            'view': ('graph.sed:=1', 'graph.seed'),
            'place': ('module.params_timeot:=1.0', 'module.params_timeout')}
    procs = {n: start(install_dir, n, tmp_path, typo[n][0]) for n in NODES}
    for name, (code, out) in finish_all(procs).items():
        key, near = typo[name][0].split(':=')[0], typo[name][1]
        assert code == 2, f'{name}: exit {code}\n{out}'
        lines = bad_lines(out)
        assert len(lines) == 1 and 'Traceback' not in out, f'{name}:\n{out}'
        assert f'unknown key {key}' in lines[0] and f'did you mean {near}?' in lines[0], out


def test_every_node_rejects_a_wrong_type_in_one_line_with_key_type_and_range(install_dir,
                                                                            tmp_path):
    procs = {n: start(install_dir, n, tmp_path, f'{NODES[n][2]}:=fast') for n in NODES}
    for name, (code, out) in finish_all(procs).items():
        key, rng = NODES[name][2], NODES[name][3]
        assert code == 2, f'{name}: exit {code}\n{out}'
        lines = bad_lines(out)
        assert len(lines) == 1 and 'Traceback' not in out, f'{name}:\n{out}'
        assert f"{key} = 'fast' must be a number, in [" in lines[0], out
        if rng:
            assert rng in lines[0], out


@pytest.fixture
def client():
    context = Context()
    rclpy.init(context=context)
    node = rclpy.create_node('param_probe', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    yield node, executor
    executor.shutdown()
    node.destroy_node()
    rclpy.shutdown(context=context)


def test_every_node_takes_an_integer_for_a_float(install_dir, tmp_path, client):
    node, executor = client
    procs = {n: start(install_dir, n, tmp_path, f'{NODES[n][2]}:=1',
                      'node.lockstep_periods:=[1, 2]' if n == 'sim' else 'use_sim_time:=false')
             for n in NODES}
    try:
        for name, proc in procs.items():
            key = NODES[name][2]
            params = AsyncParameterClient(node, f'/{name}')
            ready = params.wait_for_services(timeout_sec=90.0)
            assert ready and proc.poll() is None, f'{name}: not up\n{stop(proc)}'
            keys = [key, 'node.lockstep_periods'] if name == 'sim' else [key]
            future = params.get_parameters(keys)
            executor.spin_until_future_complete(future, timeout_sec=60.0)
            values = future.result().values
            assert values[0].type == ParameterType.PARAMETER_DOUBLE, (name, values[0])
            assert values[0].double_value == 1.0, (name, values[0])
            if name == 'sim':
                assert values[1].type == ParameterType.PARAMETER_DOUBLE_ARRAY, values[1]
                assert list(values[1].double_array_value) == [1.0, 2.0]
    finally:
        for proc in procs.values():
            stop(proc)
