"""A module plug-in from a package of its own (docs/modules.md), with no change to the repository.

A throw-away package, outside the repository, registers one module under the entry-point group
``clis.modules`` (a pyproject and one Python file, read from docs/modules.md); pip installs it
into the venv; then ``clis experiment`` and ``clis run`` run it next to the innate module: its
node is in the graph, proposes at its period, and it learns (its policy weights change).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
import re
import subprocess
import sys

import numpy as np
import pytest

pytestmark = pytest.mark.ros

DOC = Path(__file__).resolve().parent.parent / 'docs' / 'modules.md'


def doc_file(name: str) -> str:
    """The code block of docs/modules.md that starts with the comment ``# NAME``."""
    for block in re.findall(r'```\w*\n(.*?)```', DOC.read_text(encoding='utf-8'), re.S):
        if block.startswith(f'# {name}\n'):
            return block
    raise AssertionError(f'docs/modules.md has no code block of {name}')


NAME = 'frontir'
PERIOD = 0.4
CONDITION = f'async:innate+{NAME}'
#: the two files of the package, as docs/modules.md writes them
PYPROJECT = doc_file('pyproject.toml')
MODULE = doc_file(f'clis_{NAME}.py')


def test_the_documented_package_is_the_plugin_of_this_test():
    assert f'{NAME} = "clis_{NAME}:FrontIr"' in PYPROJECT
    assert f"'period': {PERIOD}," in MODULE
    assert 'class FrontIrModel(FeatureModel):' in MODULE


@pytest.fixture(scope='module')
def installed(tmp_path_factory):
    """The package built outside the repository and pip-installed; uninstalled at the end."""
    pkg = tmp_path_factory.mktemp('plugin_pkg')
    (pkg / 'pyproject.toml').write_text(PYPROJECT)
    (pkg / f'clis_{NAME}.py').write_text(MODULE)
    pip = [sys.executable, '-m', 'pip']
    out = subprocess.run([*pip, 'install', '--no-deps', '--no-build-isolation', '-q', str(pkg)],
                         capture_output=True, text=True, timeout=300)
    if out.returncode != 0 and 'bdist_wheel' in out.stdout + out.stderr:
        # the venv's setuptools (colcon's) builds no wheel without the `wheel` package: build
        # in an isolated environment from the configured index instead (the package's
        # build-system.requires); what is installed is the same
        out = subprocess.run([*pip, 'install', '--no-deps', '-q', str(pkg)],
                             capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout + out.stderr
    try:
        yield pkg
    finally:
        subprocess.run([*pip, 'uninstall', '-y', '-q', f'clis-{NAME}'], capture_output=True,
                       timeout=300)


def cli(*args: str, timeout: float) -> subprocess.CompletedProcess:
    """``clis ARGS`` in a fresh interpreter (it finds the newly installed entry point)."""
    return subprocess.run([sys.executable, '-m', 'clis_app.cli', *args],
                          capture_output=True, text=True, timeout=timeout)


def test_the_plugin_is_found_by_its_entry_point(installed):
    code = ('from clis_modules.core.plugin import get_plugin; '
            f'p = get_plugin({NAME!r}); print(type(p).__module__, p.sensors)')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split()[0] == f'clis_{NAME}'


def test_experiment_runs_and_learns_the_plugin_module(installed, tmp_path):
    out = cli('experiment', '--conditions', CONDITION, '--seeds', '1', '--episodes', '3',
              '--block', '1', '--eval-episodes', '1', '--eval-every', '0', '--workers', '1',
              '--out', str(tmp_path / 'exp'), timeout=600)
    assert out.returncode == 0, out.stdout + out.stderr
    runs = list((tmp_path / 'exp' / 'runs').glob('*.json'))
    assert len(runs) == 1
    run = json.loads(runs[0].read_text())
    assert run['modules'] == ['innate', NAME]
    ckpt = np.load(runs[0].with_suffix('.npz'))
    assert ckpt[f'{NAME}.W'].shape == (2, 7)           # 5 RBFs, not visible, front
    assert np.any(ckpt[f'{NAME}.W'] != 0.0), 'its policy learned nothing'


def test_clis_run_starts_its_node_which_proposes_at_its_period_and_learns(installed, tmp_path):
    from clis_app.bags.mcap import BagReader
    from clis_modules.conversions import proposal_from_msg
    from cr_sim.conversions import episode_from_msg
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import JointState

    short = tmp_path / 'short.yaml'
    short.write_text('/**:\n  ros__parameters:\n    episode: {time_limit: 20.0}\n')
    run, bag = tmp_path / 'run', tmp_path / 'bag'
    out = cli('run', '--condition', CONDITION, '--episodes', '2', '--quiet', '--out', str(run),
              '--params', str(short), '--record', str(bag), timeout=300)
    assert out.returncode == 0, out.stdout + out.stderr
    assert (run / 'logs' / f'{NAME}.log').is_file()             # its node, by its name
    stamps, starts = [], []
    for m in BagReader(bag).messages([f'/{NAME}/proposal', '/episode']):
        if m.topic == '/episode':
            t, event, _ = episode_from_msg(deserialize_message(m.data, DiagnosticArray))
            starts += [t] if event == 'start' else []
            continue
        p = proposal_from_msg(deserialize_message(m.data, JointState))
        assert p.module == NAME
        stamps.append(p.t)
    assert len(stamps) > 10 and len(starts) >= 2, (len(stamps), starts)
    # at t_0 + l PERIOD of its episode's start t_0, and at every such instant (the episodes
    # that ended: the run stops as the next one starts)
    for t0, t1 in zip(starts[:-1], starts[1:]):
        mine = np.array(sorted({round(t, 6) for t in stamps if t0 - 1e-6 <= t < t1 - 1e-6}))
        assert mine.size and mine[0] == pytest.approx(t0), (t0, mine[:3])
        assert np.allclose(np.diff(mine), PERIOD, atol=1e-6), np.diff(mine)
    ckpt = np.load(run / 'checkpoint.npz')
    assert np.any(ckpt[f'{NAME}.W'] != 0.0), 'its policy learned nothing'
    assert math.isfinite(float(ckpt[f'{NAME}.sigma']))


def test_a_condition_with_an_unknown_module_names_it(tmp_path):
    out = cli('experiment', '--conditions', 'async:innate+nosuchmodule', '--seeds', '1',
              '--episodes', '1', '--block', '1', '--out', str(tmp_path / 'x'), timeout=120)
    assert out.returncode == 2
    assert 'nosuchmodule' in out.stderr

