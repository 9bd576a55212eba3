"""`clis study` and `clis arena`: a bad grid value fails in one line before anything runs; an
interrupted study resumed (elsewhere, from its folder alone) reports what one run straight
through reports; the report's counts and intervals; the arena commands."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
import shutil

from clis_app.cli import main as clis
from clis_app.study import report as study_report
from clis_app.study import study
from clis_base.params import config_dir
import pytest
from test_markdown_tables import bad_rows
import yaml

#: A study of a few seconds: short episodes, two layouts, the thesis' conditions, 3 seeds.
MICRO = {'name': 'micro', 'arenas': ['mine.yaml', {'generated': {'seeds': [4]}}],
         'protocols': ['wander'],
         'presets': ['improved'], 'conditions': ['innate', 'view', 'async'], 'seeds': 3,
         'episodes': 2, 'eval_every': 1, 'eval_episodes': 1,
         'sim_set': {'episode.time_limit': 3.0}}


def _spec(folder: Path, spec: dict) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    shutil.copy(config_dir() / 'arena.yaml', folder / 'mine.yaml')
    path = folder / 'spec.yaml'
    path.write_text(yaml.safe_dump(spec))
    return path


BAD = [
    ({'protocols': ['wandr']}, "protocols[0]: 'wandr'", 'wander, starts, random'),
    ({'conditions': ['innate', 'teleport']}, "conditions[1]: 'teleport'", 'innate, view'),
    ({'conditions': ['view@common.beta=2']}, 'conditions[0]', 'TIMING:MODULE'),
    ({'presets': ['fast']}, "presets[0]: 'fast'", 'paper, improved'),
    ({'presets': [{'name': 'x', 'preset': 'fast'}]}, 'presets[0].preset', 'paper, improved'),
    ({'presets': [{'name': 'x', 'preset': 'improved', 'set': {'common.bta': 1}}]},
     'presets (x).set', 'common.bta'),
    ({'arenas': ['nowhere.yaml']}, 'arenas[0]: nowhere.yaml: no such file', 'current folder'),
    ({'arenas': [{'generated': {'seeds': [-1]}}]}, 'arenas[0].generated.seeds[0]',
     'an integer >= 0'),
    ({'arenas': [{'made': 3}]}, 'arenas[0]', 'generated: {seeds'),
    ({'seeds': 0}, 'seeds: 0', 'an integer >= 1'),
    ({'eval_every': 3}, 'eval_every: 3', 'a divisor of episodes'),
    ({'protocol': ['wander']}, 'protocol:', 'keys arenas, protocols'),
    ({'name': ['a']}, "name: ['a']", 'a string'),
    ({'sim_set': {'episode.time_limt': 1.0}}, 'sim_set', 'time_limt'),
    ({'sim_set': {'robot.radius': 0.4}}, 'arenas: mine.yaml', 'robot radius 0.4 m'),
    ({'grids': [{'seeds': 2}, {'protocols': ['nope']}]}, 'grids[1].protocols[0]', 'wander'),
    # a preset compared with another's single modules: it runs none, the other has them
    ({'presets': [{'name': 'b', 'preset': 'improved', 'singles': 'improved'}]},
     "conditions: 'innate'", 'more than one module'),
    ({'conditions': ['async'], 'presets': [{'name': 'b', 'preset': 'improved',
                                            'singles': 'improved'}]},
     'presets (b).singles: improved has no single-module run', 'add them'),
    ({'grids': [{'presets': ['improved'], 'seeds': 2},
                {'conditions': ['async'], 'presets': [{'name': 'b', 'preset': 'improved',
                                                       'singles': 'improved'}]}]},
     'presets (b).singles: improved has no single-module run on mine/wander seed 2',
     'add them'),
    ({'grids': [{'presets': ['improved']},
                {'conditions': ['async'], 'episodes': 4, 'eval_every': 2,
                 'presets': [{'name': 'b', 'preset': 'improved', 'singles': 'improved'}]}]},
     'presets (b).singles: the runs of improved', 'another episodes'),
]


@pytest.mark.parametrize('change, key, allowed', BAD, ids=[b[1] for b in BAD])
def test_a_bad_grid_value_fails_in_one_line_before_anything_runs(tmp_path, capsys, change,
                                                                  key, allowed):
    spec = _spec(tmp_path / 'spec', {**MICRO, **change})
    out = tmp_path / 'out'
    assert clis(['study', str(spec), '--out', str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and err.startswith('clis study: SPEC '), err
    assert key in err and allowed in err, err
    assert not out.exists()


def test_a_bad_flag_is_one_line_and_creates_nothing(tmp_path, capsys):
    spec = _spec(tmp_path / 'spec', MICRO)
    (tmp_path / 'bad.yaml').write_text('arenas: [unclosed')
    (tmp_path / 'empty').mkdir()
    out = str(tmp_path / 'out')
    cases = [([str(spec), '--out', out, '--workers', '0'], '--workers'),
             ([str(spec), '--out', out, '--address', 'h:1'], '--address'),
             (['--out', out], 'SPEC'), ([str(tmp_path / 'none.yaml'), '--out', out], 'none.yaml'),
             ([str(tmp_path / 'bad.yaml'), '--out', out], 'not YAML'),
             ([str(spec), '--out', str(spec)], 'not a folder'),
             (['--report-only', '--out', str(tmp_path / 'empty')], 'no run summaries'),
             ([str(spec), '--out', out, '--backend', 'slurm'], '--backend')]
    for argv, name in cases:
        try:
            code = clis(['study', *argv])
        except SystemExit as exc:                  # argparse's own (a choice not allowed)
            code = exc.code
        assert code == 2, argv
        err = capsys.readouterr().err
        assert err.count('\n') == 1 and name in err, (argv, err)
        assert not Path(out).exists(), argv


def _report(out: Path) -> tuple[str, str]:
    return (out / 'report.md').read_text(), (out / 'report.json').read_text()


def _summaries(out: Path) -> dict[str, dict]:
    got = {}
    for p in sorted((out / 'runs').rglob('*.json')):
        data = json.loads(p.read_text())
        data.pop('seconds')
        got[str(p.relative_to(out))] = data
    return got


def test_an_interrupted_study_resumed_elsewhere_reports_what_one_run_straight_through_does(
        tmp_path, capsys, monkeypatch):
    spec = _spec(tmp_path / 'spec', MICRO)
    straight = tmp_path / 'straight'
    assert clis(['study', str(spec), '--out', str(straight), '--workers', '2',
                 '--quiet']) == 0
    n_runs = len(_summaries(straight))
    assert n_runs == 2 * 3 * 3
    # interrupted (Ctrl-C) after 5 runs were stored
    stored = study._store
    calls = []

    def store_then_stop(*args, **kwargs):
        stored(*args, **kwargs)
        calls.append(1)
        if len(calls) == 5:
            raise KeyboardInterrupt
    monkeypatch.setattr(study, '_store', store_then_stop)
    first = tmp_path / 'first'
    assert clis(['study', str(spec), '--out', str(first), '--workers', '2', '--quiet']) == 130
    monkeypatch.setattr(study, '_store', stored)
    assert 5 <= len(_summaries(first)) < n_runs
    assert not (first / 'report.md').exists()
    capsys.readouterr()
    # the same command again, without --resume: one line, nothing run
    assert clis(['study', str(spec), '--out', str(first)]) == 2
    assert '--resume' in capsys.readouterr().err
    # "another machine": the folder alone, the SPEC's arena file gone
    moved = tmp_path / 'elsewhere' / 'first'
    shutil.copytree(first, moved)
    shutil.rmtree(first)
    (tmp_path / 'spec' / 'mine.yaml').unlink()
    kept = {p: p.stat().st_mtime_ns for p in (moved / 'runs').rglob('*.json')}
    assert clis(['study', '--resume', '--out', str(moved), '--workers', '2', '--quiet']) == 0
    assert _summaries(moved) == _summaries(straight)
    assert _report(moved) == _report(straight)
    assert {p: p.stat().st_mtime_ns for p in kept} == kept       # the finished runs were kept
    # the report is redrawn from the summaries alone
    for name in ('report.md', 'report.json', 'forest.png', 'hidden_share.png', 'layouts.png'):
        (moved / name).unlink()
    shutil.rmtree(moved / 'work')
    # a run of an earlier, larger SPEC left in DIR/runs is not reported, and the report says
    # how many summaries it read and how many it left out
    one = next((moved / 'runs').rglob('view__s1.json'))
    stray = json.loads(one.read_text())
    stray.update(seed=7, final={'episode': 2, 'reached': 5, 'n': 5})
    one.with_name('view__s7.json').write_text(json.dumps(stray))
    assert clis(['study', '--report-only', '--out', str(moved)]) == 0
    md, numbers = _report(moved)
    read = f'{n_runs} run summaries read of {n_runs} runs planned.'
    assert read in _report(straight)[0]
    assert md == _report(straight)[0].replace(read, read + ' 1 more summary in the runs folder '
                                              'is of runs outside the plan, not reported.')
    assert json.loads(numbers) == {**json.loads(_report(straight)[1]), 'outside_plan': 1}
    one.with_name('view__s7.json').unlink()
    assert clis(['study', '--report-only', '--out', str(moved)]) == 0
    assert _report(moved) == _report(straight)
    assert (moved / 'forest.png').stat().st_size > 0
    assert (moved / 'hidden_share.png').stat().st_size > 0
    assert (moved / 'layouts.png').stat().st_size > 0
    assert bad_rows((moved / 'report.md').read_text()) == []
    # a resume whose settings differ from the saved runs' stops in one line
    changed = _spec(tmp_path / 'spec2', {**MICRO, 'episodes': 4})
    capsys.readouterr()
    assert clis(['study', str(changed), '--out', str(moved), '--resume']) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and 'other settings' in err and 'episodes=2' in err, err
    # so does one whose learning parameters changed (a preset file edited, say)
    saved = next((moved / 'runs').rglob('view__s1.json'))
    saved.write_text(saved.read_text().replace('"params_hash": "', '"params_hash": "x'))
    assert clis(['study', '--resume', '--out', str(moved)]) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and 'view__s1.json' in err and 'parameters (hash x' in err, err
    assert (moved / 'report.md').read_text().startswith('# Study report: micro\n')


def _summary(arena: str, condition: str, seed: int, reached: int, solo: dict | None = None,
             layout_seed: int | None = 1) -> dict:
    return {'format': study.SUMMARY_FORMAT, 'arena': arena, 'protocol': 'wander',
            'preset': 'improved', 'condition': condition, 'seed': seed,
            'settings': {'layout_seed': layout_seed}, 'hidden_share': 0.1,
            'final': {'episode': 10, 'reached': reached, 'n': 50},
            'solo': solo or {}, 'eval_curve': [], 'modules': [], 'params_hash': ''}


def test_the_report_counts_layouts_above_and_below_with_their_intervals():
    rows = []
    # layout up: Async well above both singles; down: below the best; flat: not resolved
    levels = {'up': (20, 30, 40), 'down': (20, 30, 10), 'flat': (20, 30, 30)}
    for arena, (innate, view, asy) in levels.items():
        for seed in range(4):
            jitter = seed % 2
            rows.append(_summary(arena, 'innate', seed, innate + jitter))
            rows.append(_summary(arena, 'view', seed, view + jitter))
            solo = {'view': {'reached': view + 5 + jitter, 'n': 50}}  # M_vi alone: +10 points
            rows.append(_summary(arena, 'async', seed, asy + jitter - (seed == 3), solo))
    for seed in range(4):                       # a layout from a file (no layout seed)
        for cond, level in (('innate', 10), ('view', 12), ('async', 45 + seed % 2)):
            rows.append(_summary('designed', cond, seed, level, layout_seed=None))
    rep = study_report.report(rows, planned=len(rows))
    (g,) = rep['numbers']['groups']
    assert {a: c['async_best']['verdict'] for a, c in g['layouts'].items()} == \
        {'up': 'above', 'down': 'below', 'flat': '', 'designed': 'above'}
    # above every single module: judged on each single module's interval
    assert {a: c['async_all']['verdict'] for a, c in g['layouts'].items()} == \
        {'up': 'above', 'down': '', 'flat': '', 'designed': 'above'}
    assert {a: c['async_minus']['innate']['verdict'] for a, c in g['layouts'].items()} == \
        {'up': 'above', 'down': 'below', 'flat': 'above', 'designed': 'above'}
    assert g['aggregate']['async_all'] == {'above': 1, 'layouts': 3, 'interval': True,
                                           'verdict': ''}
    assert {a: c['async_best']['best'] for a, c in g['layouts'].items()} == \
        {'up': 'view', 'down': 'view', 'flat': 'view', 'designed': 'view'}
    ab = g['aggregate']['async_best']
    assert (ab['above'], ab['below'], ab['unresolved'], ab['layouts']) == (1, 1, 1, 3)
    up = g['layouts']['up']['async_best']
    assert up['mean'] == pytest.approx(2 * (40 - 30) - 0.5)      # points: 2 per success of 50
    assert 0 < up['half'] < up['mean']
    assert ab['mean'] == pytest.approx((19.5 - 40.5 - 0.5) / 3)
    th = g['aggregate']['thesis_view']
    assert (th['above'], th['below'], th['layouts']) == (3, 0, 3)
    assert (ab['verdict'], th['verdict']) == ('', 'above')           # over layouts
    assert th['mean'] == pytest.approx(10.0) and th['half'] == pytest.approx(0.0)
    assert 'thesis_place' not in g['aggregate']          # no Place condition: no test
    md = rep['markdown']
    assert bad_rows(md) == []
    assert '| improved | wander | 4 | 3 generated | on 1 of 3; over layouts: not above | ' in md
    assert '| -7.2 ± ' in md and ' (1 above, 1 below, 1 not resolved) |' in md
    # the layout designed by hand is in the table, not in the aggregate over generated ones
    assert g['layouts']['designed']['async_best']['verdict'] == 'above'
    assert g['aggregate']['over'] == 'generated' and g['aggregate']['n_layouts'] == 3
    assert '+19.5 ±' in md and '(view) **above**' in md


def test_a_preset_with_singles_is_compared_with_the_other_presets_single_modules():
    rows = []
    for seed in range(4):
        rows.append(_summary('up', 'innate', seed, 20 + seed % 2))
        rows.append(_summary('up', 'view', seed, 30 + seed % 2))
        rows.append(_summary('up', 'async', seed, 25 + seed % 2))
        bonus = _summary('up', 'async', seed, 40 + seed % 2 - (seed == 3))
        bonus.update(preset='improved+bonus', settings={'layout_seed': 1,
                                                        'singles': 'improved'})
        rows.append(bonus)
    rep = study_report.report(rows)
    groups = {g['preset']: g for g in rep['numbers']['groups']}
    assert groups['improved']['layouts']['up']['async_best']['verdict'] == 'below'
    b = groups['improved+bonus']
    assert b['singles_from'] == 'improved' and b['conditions'] == ['innate', 'view', 'async']
    cell = b['layouts']['up']
    assert cell['async_best']['verdict'] == 'above' and cell['async_best']['best'] == 'view'
    assert cell['conditions']['view'] == groups['improved']['layouts']['up']['conditions'][
        'view']
    assert 'view_innate' not in cell                   # the other preset's, drawn once
    assert cell['async_vs_base']['mean'] == pytest.approx(2 * 15 - 0.5)    # 40 - 25 of 50
    assert cell['async_vs_base']['verdict'] == 'above'
    assert 'async_vs_base' not in groups['improved']['layouts']['up']
    assert 'The single modules are the runs of preset improved' in rep['markdown']
    assert bad_rows(rep['markdown']) == []


def test_arena_generate_writes_the_same_bytes_and_show_checks_and_draws(tmp_path, capsys):
    a, b = tmp_path / 'a.yaml', tmp_path / 'b.yaml'
    assert clis(['arena', 'generate', '--seed', '9', '--out', str(a)]) == 0
    assert clis(['arena', 'generate', '--seed', '9', '--out', str(b), '--png',
                 str(tmp_path / 'b.png')]) == 0
    assert a.read_bytes() == b.read_bytes() and (tmp_path / 'b.png').stat().st_size > 0
    capsys.readouterr()
    assert clis(['arena', 'generate', '--seed', '9']) == 0
    assert capsys.readouterr().out == a.read_text()
    assert clis(['arena', 'show', str(a), '--png', str(tmp_path / 'a.png')]) == 0
    out = capsys.readouterr().out
    assert out.count('in its situation') == 5 and 'NOT' not in out
    assert clis(['arena', 'show', str(config_dir() / 'arena_alt.yaml')]) == 1
    assert 'C: NOT in its situation' in capsys.readouterr().out
    for argv, name in ((['generate', '--seed', '-1'], '--seed'),
                       (['generate', '--seed', '1', '--out', str(tmp_path / 'no' / 'x.yaml')],
                        '--out'), (['show', str(tmp_path / 'none.yaml')], 'none.yaml')):
        assert clis(['arena', *argv]) == 2
        err = capsys.readouterr().err
        assert err.count('\n') == 1 and name in err, err


def test_a_reader_that_stops_early_gets_no_traceback(tmp_path):
    """``clis study SPEC --plan | head -1``: the pipe closes before clis has written."""
    import subprocess
    import sys
    spec = _spec(tmp_path / 'spec', MICRO)
    read, write = os.pipe()
    os.close(read)                                # the reader is gone before any output
    proc = subprocess.run([sys.executable, '-m', 'clis_app.cli', 'study', str(spec), '--plan',
                           '--out', str(tmp_path / 'out')], stdout=write,
                          stderr=subprocess.PIPE, text=True, timeout=120,
                          env={**os.environ, 'PYTHONPATH': os.pathsep.join(sys.path)})
    os.close(write)
    assert proc.returncode == 0 and 'Traceback' not in proc.stderr, proc.stderr


def test_the_report_counts_the_runs_in_which_a_module_diverged():
    rows = [dict(_summary('gen-a', c, s, 20), diverged={})
            for c in ('innate', 'view', 'async') for s in range(3)]
    rows[-1]['diverged'] = {'view': 18}
    old = [_summary('gen-b', c, 0, 20) for c in ('innate', 'view', 'async')]   # no record
    out = study_report.report(rows + old)
    d = out['numbers']['groups'][0]['diverged']
    assert (d['runs'], d['recorded'], d['diverged']) == (12, 9, 1)
    assert d['conditions'] == {'innate': [0, 3], 'view': [0, 3], 'async': [1, 3]}
    assert '| improved | wander | 12 | 9 | 1 | async 1/3 |' in out['markdown']
    assert '## Divergence' in out['markdown']


def test_leave_one_out_chooses_the_best_single_on_the_other_seeds():
    # View is best on the mean over all four seeds (42.5 against 40), by its two good seeds:
    # chosen on the same seeds it is compared on, the choice favours it
    innate = {s: 40.0 for s in range(4)}
    view = {0: 90.0, 1: 70.0, 2: 10.0, 3: 0.0}
    asy = {s: 50.0 for s in range(4)}
    got = study_report.leave_one_out_best(asy, {'innate': innate, 'view': view})
    # seed 0: the others' view mean is 26.7 < 40, innate; seed 1: 33.3, innate; seeds 2, 3:
    # 53.3 and 56.7, view
    assert got == {0: ('innate', 10.0), 1: ('innate', 10.0), 2: ('view', 40.0),
                   3: ('view', 50.0)}
    # a tie goes to the module listed first; a module without the seed is not a candidate
    tie = study_report.leave_one_out_best({0: 5.0, 1: 5.0, 2: 5.0},
                                          {'view': {0: 1.0, 1: 1.0, 2: 1.0},
                                           'innate': {0: 1.0, 1: 1.0}})
    assert tie == {0: ('view', 4.0), 1: ('view', 4.0), 2: ('view', 4.0)}
    assert study_report.leave_one_out_best({0: 5.0}, {'view': {0: 1.0}}) == {}   # no other seed
    # the same from run summaries: the report's two comparators side by side
    rows = []
    for seed in range(4):
        rows.append(_summary('gen-a', 'innate', seed, 20))
        rows.append(_summary('gen-a', 'view', seed, int(view[seed]) // 2))
        rows.append(_summary('gen-a', 'async', seed, 25))
    (g,) = study_report.report(rows)['numbers']['groups']
    cell = g['layouts']['gen-a']
    assert cell['async_best']['best'] == 'view'
    assert cell['async_best']['mean'] == pytest.approx((-40 - 20 + 40 + 50) / 4)    # 7.5
    loo = cell['async_best_loo']
    assert loo['mean'] == pytest.approx((10 + 10 + 40 + 50) / 4)                   # 27.5
    assert loo['chosen'] == {'0': 'innate', '1': 'innate', '2': 'view', '3': 'view'}
    assert cell['async_minus']['innate']['mean'] == pytest.approx(10.0)
    assert cell['async_minus']['view']['mean'] == pytest.approx(7.5)
    assert g['aggregate']['async_best_loo']['mean'] == pytest.approx(27.5)
    md = study_report.report(rows)['markdown']
    assert '+27.5 ± ' in md and '(innate 2, view 2)' in md and '+7.5 ± ' in md
    assert bad_rows(md) == []


def test_success_rate_intervals_stay_within_0_and_100():
    # a module that learns on one seed of four: 0, 0, 0, 100%; the t-interval runs from -55
    # to +105
    got = study_report.rate_interval([0.0, 0.0, 0.0, 100.0])
    assert got['mean'] == pytest.approx(25.0) and got['half'] > 75.0
    assert (got['low'], got['high']) == (0.0, 100.0)
    inner = study_report.rate_interval([40.0, 50.0, 60.0])
    assert (inner['low'], inner['high']) == pytest.approx((50.0 - inner['half'],
                                                           50.0 + inner['half']))
    assert 0.0 < inner['low'] < 50.0 < inner['high'] < 100.0          # inside: not clipped
    few = study_report.rate_interval([0.0, 100.0])              # no interval below 3 values
    assert few['mean'] == 50.0 and math.isnan(few['low']) and math.isnan(few['high'])
    rows = []
    for seed in range(4):
        rows.append(_summary('gen-a', 'innate', seed, 48 + seed % 2))
        rows.append(_summary('gen-a', 'view', seed, 50 if seed == 3 else 0))
        rows.append(_summary('gen-a', 'async', seed, 25))
    rep = study_report.report(rows)
    (g,) = rep['numbers']['groups']
    for cond in g['layouts']['gen-a']['conditions'].values():
        assert 0.0 <= cond['low'] <= cond['mean'] <= cond['high'] <= 100.0
    view = g['layouts']['gen-a']['conditions']['view']
    assert (view['low'], view['high']) == (0.0, 100.0)
    assert '| 25.0 [0.0, 100.0] |' in rep['markdown']
    assert ' ± ' not in rep['markdown'].split('Final evaluated success [%]:')[1].split(
        'Differences')[0]


def test_the_share_of_runs_below_innates_level():
    assert study_report.below_level([10.0, 40.0, 39.0, 90.0, math.nan], 40.0) == (2, 4)
    rows = []
    for arena, view in (('gen-a', (45, 35, 5, 0)), ('gen-b', (45, 45, 20, 45))):
        for seed in range(4):
            rows.append(_summary(arena, 'innate', seed, (19, 21, 20, 20)[seed]))    # mean 40%
            rows.append(_summary(arena, 'view', seed, view[seed]))
            rows.append(_summary(arena, 'async', seed, 20))           # at Innate's mean
    rep = study_report.report(rows)
    (g,) = rep['numbers']['groups']
    a, b = g['layouts']['gen-a']['conditions'], g['layouts']['gen-b']['conditions']
    assert a['view']['below_innate'] == [2, 4] and b['view']['below_innate'] == [0, 4]
    assert a['async']['below_innate'] == [0, 4]          # equal to the level is not below
    assert 'below_innate' not in a['innate']
    assert g['aggregate']['conditions']['view']['below_innate'] == [2, 8]
    md = rep['markdown']
    assert '| view below innate |' in md and '| 2/4 |' in md and '| 2/8 |' in md
    assert '; 2/8 below innate' in md
