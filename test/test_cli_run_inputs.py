"""``clis run``'s argument surface: every malformed input is refused before anything starts.

For each option, malformed values: exit code 2, one line on stderr naming the option, never a
traceback, and nothing created on disk (an empty working folder, a ``--out`` that does not
exist yet; the whole temporary tree is compared before and after). The values of a ``--params``
file are checked as the nodes will check them (``config/clis.yaml``, ``graph.yaml``,
``sim.yaml``, ``bridge.yaml`` keys): a bad one names the key and the allowed range. The same
key check serves ``clis experiment --set`` (core.config.check_overrides).
"""

from __future__ import annotations

from pathlib import Path
import subprocess
import sys

from clis_learner.core.checkpoint import save_checkpoint
from clis_learner.core.config import (
    DEFAULT_PRESET,
    load_clis_params,
    params_hash,
    preset_overrides,
)
from clis_modules.core.modules import arena_map, make_modules
from cr_sim.core.arena import load_arena
import pytest

from clis_app import cli

PARAMS = {
    'unknown.yaml': '/**:\n  ros__parameters:\n    common: {bta: 200.0}\n',
    'clis_value.yaml': '/**:\n  ros__parameters:\n    common: {beta: fast}\n',
    'graph_value.yaml': '/**:\n  ros__parameters:\n    graph: {seed: -1}\n',
    'graph_choice.yaml': '/**:\n  ros__parameters:\n    graph: {executor: fast}\n',
    'sim_value.yaml': 'sim:\n  ros__parameters:\n    episode: {time_limit: -4.0}\n',
    'sim_node.yaml': '/**:\n  ros__parameters:\n    node: {speed_factor: 5000.0}\n',
    'bridge_value.yaml': 'bridge:\n  ros__parameters:\n    node: {watchdog: 9.0}\n',
    'typo.yaml': '/**:\n  ros__parameters:\n    node: {sped_factor: 5.0}\n',
    'not_ros.yaml': '- a\n- b\n',
    'no_section.yaml': '/**:\n  common: {beta: 2.0}\n',
    'broken.yaml': 'a: [\n',
}


@pytest.fixture(scope='module')
def inputs(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp('inputs')
    for name, text in PARAMS.items():
        (folder / name).write_text(text)
    (folder / 'arena_bad.yaml').write_text('obstacles: 3\n')
    (folder / 'garbage.npz').write_bytes(b'not a checkpoint')
    (folder / 'a_file').write_text('x')
    clis = load_clis_params(overrides=preset_overrides(DEFAULT_PRESET))   # clis run's default
    modules = make_modules(clis, 'innate', *arena_map(load_arena()))
    save_checkpoint(folder / 'innate.npz', modules, params_hash(clis),
                    {'condition': 'innate', 'seed': 0, 'episode': 3, 'version': 3})
    return folder


def cases(i: Path) -> list[tuple[str, list[str], str]]:
    """(option, arguments, a text the error line must hold besides the option)."""
    p = [(f'--params {n}', ['--params', str(i / n)], text) for n, text in (
        ('unknown.yaml', 'unknown key common.bta; did you mean common.beta?'),
        ('clis_value.yaml', "common.beta = 'fast' must be a number, in [0.0, "),
        ('graph_value.yaml', 'graph.seed = -1 is out of range: must be in [0, 2147483647]'),
        ('graph_choice.yaml', "graph.executor = 'fast' is not allowed: must be one of 'lean'"),
        ('sim_value.yaml', 'episode.time_limit = -4.0 is out of range: must be in [0.01, '),
        ('sim_node.yaml', 'node.speed_factor = 5000.0 is out of range: must be in [0.0, 1000.0]'),
        ('typo.yaml', 'unknown key node.sped_factor; did you mean node.speed_factor?'),
        ('not_ros.yaml', 'expected a mapping'),
        ('no_section.yaml', 'ros__parameters'),
        ('broken.yaml', 'not valid YAML'),
        ('missing.yaml', 'no such file'))]
    return p + [
        ('--params bridge_value.yaml', ['--robot', 'bridge', '--params',
                                        str(i / 'bridge_value.yaml')],
         'node.watchdog = 9.0 is out of range: must be in [0.01, 0.3]'),
        ('--condition', ['--condition', 'nope'], "unknown condition 'nope'"),
        ('--episodes', ['--episodes', 'abc'], 'invalid int'),
        ('--episodes', ['--episodes', '0'], 'at least 1'),
        ('--episodes', ['--episodes', '-3'], 'at least 1'),
        ('--speed', ['--speed', 'fast'], 'invalid float'),
        ('--speed', ['--speed', '-1'], '[0, 1000]'),
        ('--speed', ['--speed', 'inf'], '[0, 1000]'),
        ('--speed', ['--speed', 'nan'], '[0, 1000]'),
        ('--seed', ['--seed', 'x'], 'invalid int'),
        ('--seed', ['--seed', '-1'], '[0, 2^31)'),
        ('--seed', ['--seed', '2147483648'], '[0, 2^31)'),
        ('--resume', ['--resume', str(i / 'missing.npz')], 'no such checkpoint'),
        ('--resume', ['--resume', str(i / 'garbage.npz')], 'not a readable checkpoint'),
        ('--resume', ['--resume', str(i / 'innate.npz'), '--condition', 'view'], 'no view.w'),
        ('--resume', ['--resume', str(i / 'innate.npz'), '--condition', 'innate', '--seed',
                      '1'], 'a checkpoint of --seed 0'),
        ('--out', ['--out', str(i / 'a_file')], 'not a folder'),
        ('--arena', ['--arena', str(i / 'missing.yaml')], 'no such file'),
        ('--arena', ['--arena', str(i / 'arena_bad.yaml')], ''),
        ('--robot', ['--robot', 'car'], 'invalid choice'),
        ('--device', ['--robot', 'bridge', '--device', 'udp://x'], 'udp://HOST:PORT'),
        ('--device', ['--robot', 'bridge', '--device', 'foo://x'], 'unknown link scheme'),
        ('--device', ['--robot', 'bridge', '--device', '/dev/no-such-tty'], 'no such serial'),
        ('--speed', ['--robot', 'bridge', '--device', 'udp://127.0.0.1:9', '--speed', '3'],
         'real time'),
        ('--block', ['--block', 'x'], 'invalid int'),
        ('--block', ['--block', '0'], 'at least 1'),
        ('--time-limit', ['--time-limit', 'x'], 'invalid float'),
        ('--time-limit', ['--time-limit', '-1'], '>= 0'),
        ('--max-restarts', ['--max-restarts', 'x'], 'invalid int'),
        ('--max-restarts', ['--max-restarts', '-1'], '>= 0'),
        ('--startup-timeout', ['--startup-timeout', '0'], '> 0'),
        ('--startup-timeout', ['--startup-timeout', 'x'], 'invalid float'),
        ('--record', ['--record', str(i / 'a_file')], 'not a folder'),
        ('--foxglove', ['--foxglove', 'x'], 'invalid int'),
        ('--foxglove-wait', ['--foxglove-wait'], 'add --foxglove'),
        ('--realtime', ['--realtime', '200'], '[1, 97]'),
        ('--realtime', ['--realtime', 'x'], 'invalid int'),
        ('--real-time', ['--real-time'], 'use --speed 1'),
        ('--single-process', ['--single-process', '--robot', 'bridge'], 'not with --robot'),
        ('--robot', ['--robot', 'ros'], 'add --profile NAME'),
        ('--profile', ['--robot', 'ros', '--profile', 'nosuch'], 'nosuch'),
        ('--profile', ['--profile', 'husky'], 'only with --robot ros'),
        ('--lockstep', ['--lockstep'], 'only with --robot ros'),
        ('--speed', ['--robot', 'ros', '--profile', 'husky', '--speed', '2'], 'own clock'),
        ('--arena', ['--robot', 'ros', '--profile', 'husky', '--arena', str(i / 'arena_bad.yaml')],
         "the profile's"),
    ]


def tree(root: Path) -> dict[str, tuple[int, int]]:
    return {str(p.relative_to(root)): (p.stat().st_size, p.stat().st_mtime_ns)
            for p in sorted(root.rglob('*'))}


def clis(argv: list[str], capsys) -> tuple[int, str, str]:
    try:
        code = cli.main(argv)
    except SystemExit as exc:
        code = exc.code
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_every_malformed_option_exits_2_with_one_line_and_writes_nothing(
        inputs, tmp_path, monkeypatch, capsys):
    cwd = tmp_path / 'cwd'
    cwd.mkdir()
    monkeypatch.chdir(cwd)
    out = tmp_path / 'out'
    before, inputs_before = tree(tmp_path), tree(inputs)
    failures = []
    for option, args, text in cases(inputs):
        argv = ['run', '--out', str(out), *args] if '--out' not in args else ['run', *args]
        if '--time-limit' not in args:      # a check that let the run start: it ends, exit 0
            argv += ['--time-limit', '0.1']
        code, stdout, err = clis(argv, capsys)
        lines = [s for s in err.splitlines() if s.strip()]
        ok = (code == 2 and len(lines) == 1 and not stdout and 'Traceback' not in err
              and option.split()[0] in lines[0] and text in lines[0])
        if not ok:
            failures.append(f'{option} {args}: exit {code}, stderr:\n{err}{stdout}')
        if tree(tmp_path) != before or tree(inputs) != inputs_before:
            failures.append(f'{option} {args}: created or changed files')
            break
    assert not failures, '\n'.join(failures)


def test_the_entry_point_refuses_a_missing_arena_at_once_without_traceback(tmp_path):
    """The installed path (a process): `clis run --arena /nonexistent.yaml` used to start the
    graph, print '100 episodes', fail 10 s later in a module node and leave OUT/logs."""
    out = tmp_path / 'out'
    res = subprocess.run([sys.executable, '-m', 'clis_app.cli', 'run', '--arena',
                          '/nonexistent.yaml', '--out', str(out)], cwd=tmp_path,
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 2, res.stderr
    assert res.stderr.strip() == 'clis run: --arena /nonexistent.yaml: no such file'
    assert sorted(tmp_path.iterdir()) == []


def test_clis_experiment_set_uses_the_same_key_check_and_blames_the_flag(tmp_path,
                                                                        monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    code, _, err = clis(['experiment', '--set', 'common.bta=2', '--episodes', '50',
                         '--out', str(tmp_path / 'exp')], capsys)
    assert code == 2, err
    assert '--set: unknown key common.bta; did you mean common.beta?' in err, err
    assert 'clis.yaml' not in err, err
