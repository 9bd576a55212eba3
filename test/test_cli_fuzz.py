"""The argument surface of `clis` (every subcommand but `run`, whose own test covers it): a
malformed value for each option -- wrong type, out of range, unknown name, nonexistent path --
exits 2 with one line on stderr naming the option, never a traceback, and creates nothing on
disk. Each case runs in an empty folder, with any output folder inside it."""

from __future__ import annotations

import os
from pathlib import Path

from clis_app.cli import main as clis
import pytest

#: (arguments, what the one line must name); OUT is replaced by a path in the empty folder.
EXPERIMENT = [
    (['--episodes', 'x'], '--episodes'), (['--episodes', '0'], '--episodes'),
    (['--episodes', '-3'], '--episodes'), (['--episodes', '2.5'], '--episodes'),
    (['--seeds', 'x'], '--seeds'), (['--seeds', '0'], '--seeds'),
    (['--first-seed', 'x'], '--first-seed'), (['--first-seed', '-1'], '--first-seed'),
    (['--eval-episodes', 'x'], '--eval-episodes'), (['--eval-episodes', '-1'], '--eval-episodes'),
    (['--eval-every', 'x'], '--eval-every'), (['--eval-every', '-5'], '--eval-every'),
    (['--block', 'x'], '--block'), (['--block', '0'], '--block'),
    (['--block', '100000'], '--block'),
    (['--workers', 'x'], '--workers'), (['--workers', '0'], '--workers'),
    (['--preset', 'nope'], '--preset'), (['--backend', 'nope'], '--backend'),
    (['--address', 'host:1'], '--address'),
    (['--train-start', 'Z'], '--train-start'),
    (['--conditions', 'teleport'], 'teleport'), (['--conditions', ','], '--conditions'),
    (['--conditions', 'view,view'], 'view'),
    (['--conditions', 'async@common.beta'], 'common.beta'),
    (['--conditions', 'async@common.beta=-1.0'], 'common.beta'),
    (['--conditions', 'async@common.bta=1'], 'common.bta'),
    (['--set', 'common.beta'], '--set'), (['--set', 'common.bta=2'], '--set'),
    (['--set', 'common.beta=fast'], '--set'), (['--set', 'common.beta=-1'], '--set'),
    (['--sim-set', 'sensors'], '--sim-set'), (['--sim-set', 'sensors.nope=1'], '--sim-set'),
    (['--sim-set', 'sensors.ir_noise_sigma=x'], '--sim-set'),
    (['--arena', 'nonexistent.yaml'], '--arena'), (['--arena', 'FILE'], '--arena'),
    (['--out', 'FILE'], '--out'), (['--preset', 'paper', '--ablation'], '--ablation'),
    (['--figures-only'], 'experiment.json'), (['--resume', '--out'], '--out'),
    (['--unknown-flag'], '--unknown-flag'),
]
REPORT = [([], 'folders'), (['nonexistent'], 'nonexistent'), (['EMPTY'], 'EMPTY'),
          (['BROKEN'], 'BROKEN'), (['--unknown-flag', 'EMPTY'], '--unknown-flag')]
COMPARE = [
    (['--b', 'EMPTY', '--condition', 'view'], '--a'),
    (['--a', 'nonexistent', '--b', 'nonexistent', '--condition', 'view'], '--a'),
    (['--a', 'RUN', '--b', 'nonexistent', '--condition', 'view'], '--b'),
    (['--a', 'RUN', '--b', 'RUN'], '--condition'),
    (['--a', 'RUN', '--b', 'RUN', '--condition', 'teleport'], '--condition'),
    (['--a', 'RUN', '--b', 'RUN', '--condition', 'view', '--block', 'x'], '--block'),
    (['--a', 'RUN', '--b', 'RUN', '--condition', 'view', '--block', '0'], '--block'),
    (['--a', 'RUN', '--b', 'RUN', '--condition', 'view', '--block', '1000'], '--block'),
    (['--a', 'RUN', '--b', 'RUN', '--condition', 'view', '--png', 'no/such/dir/x.png'],
     '--png'),
    (['--a', 'BROKEN_RUN', '--b', 'RUN', '--condition', 'view'], 'episodes'),
]
GLOBAL = [(['--domain-id', 'x', 'doctor'], '--domain-id'),
          (['--domain-id', '999', 'doctor'], '--domain-id'),
          (['--domain-id', '-1', 'doctor'], '--domain-id'),
          (['nosuchcommand'], 'nosuchcommand'), ([], 'COMMAND'),
          (['doctor', '--unknown-flag'], '--unknown-flag')]
#: The bag commands' malformed values that argparse catches (valid ones start ROS nodes).
BAGS = [(['record', '--compression', 'nope'], '--compression'),
        (['replay', 'BAG', '--rate', 'x'], '--rate'),
        (['replay', 'BAG', '--clock', 'x'], '--clock'),
        (['replay', 'BAG', '--delay', 'x'], '--delay'), (['replay'], 'bag'),
        (['learn'], 'BAG'), (['bag'], 'ACTION'), (['bag', 'info'], 'bag'),
        (['bag', 'info', 'nonexistent'], 'nonexistent')]

ARENA = [([], 'ACTION'), (['generate'], '--seed'), (['generate', '--seed', 'x'], '--seed'),
         (['generate', '--seed', '-1'], '--seed'),
         (['generate', '--seed', '1', '--out', 'EMPTY'], '--out'),
         (['generate', '--seed', '1', '--png', 'no/such/dir/x.png'], '--png'),
         (['show'], 'file'), (['show', 'nonexistent'], 'nonexistent'), (['show', 'FILE'], 'FILE')]
STUDY = [(['--out', 'OUT'], 'SPEC'), (['nonexistent.yaml', '--out', 'OUT'], 'nonexistent'),
         (['FILE', '--out', 'OUT'], 'FILE'), (['--report-only', '--out', 'EMPTY'], 'EMPTY'),
         (['--report-only', '--out', 'BROKEN'], 'BROKEN'), (['FILE'], '--out'),
         (['FILE', '--out', 'OUT', '--workers', 'x'], '--workers'),
         (['FILE', '--out', 'OUT', '--backend', 'nope'], '--backend')]

CASES = ([(['experiment', '--out', 'OUT', *a], m) for a, m in EXPERIMENT]
         + [(['arena', *a], m) for a, m in ARENA] + [(['study', *a], m) for a, m in STUDY]
         + [(['report', *a], m) for a, m in REPORT]
         + [(['compare', *a], m) for a, m in COMPARE]
         + GLOBAL + BAGS)


def _tree(root: Path) -> dict[str, bytes | None]:
    return {str(p.relative_to(root)): (p.read_bytes() if p.is_file() else None)
            for p in sorted(root.rglob('*'))}


@pytest.fixture
def place(tmp_path, monkeypatch) -> Path:
    """An empty working folder with the inputs that the cases name: FILE (not an arena),
    EMPTY (a folder without runs), BROKEN (an experiment folder whose run is damaged), RUN
    (a clis run output) and BROKEN_RUN (its episodes.csv without the episode column)."""
    (tmp_path / 'FILE').write_text('not: [an arena')
    (tmp_path / 'EMPTY').mkdir()
    (tmp_path / 'BROKEN' / 'runs').mkdir(parents=True)
    (tmp_path / 'BROKEN' / 'runs' / 'view__s0.json').write_text('{"spec": ')
    (tmp_path / 'RUN').mkdir()
    (tmp_path / 'RUN' / 'episodes.csv').write_text(
        'condition,seed,phase,episode,reached\n'
        + ''.join(f'view,0,train,{k},{k % 2}\n' for k in range(10)))
    (tmp_path / 'BROKEN_RUN').mkdir()
    (tmp_path / 'BROKEN_RUN' / 'episodes.csv').write_text('condition,reached\nview,1\n')
    monkeypatch.chdir(tmp_path)
    return tmp_path


@pytest.mark.parametrize('argv, names', CASES, ids=lambda v: ' '.join(v) if isinstance(
    v, list) else None)
def test_a_malformed_value_is_one_line_exit_2_and_creates_nothing(place, capsys, argv,
                                                                   names):
    before = _tree(place)
    argv = [str(place / 'OUT') if a == 'OUT' else a for a in argv]
    capsys.readouterr()
    try:
        code = clis(argv)
    except SystemExit as exc:
        code = exc.code
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert code == 2, (code, err)
    assert 'Traceback' not in err and len(err.splitlines()) == 1, err
    assert names in err, err
    assert _tree(place) == before, 'a rejected command changed the disk'
    assert not os.path.exists(place / 'OUT')
