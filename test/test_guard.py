"""The divergence guard (clis_learner.core.guard) and the default preset.

The guard reports a module whose values left every possible return, once, and changes no
number; a literal ``paper`` run that diverges is reported, an ``improved`` run of the same
length is not; both commands default to the preset that learns.
"""

from __future__ import annotations

import math

from clis_app.cli import build_parser
from clis_app.experiments.runner import JobSpec, run_job
from clis_app.graph.curve import divergences, summary, write_curve
from clis_learner.core.config import DEFAULT_PRESET, preset_overrides
from clis_learner.core.guard import FACTOR, Divergence, DivergenceGuard
import pytest


def _diag(**kw):
    d = {'n_steps': 10.0, 'diverged': 0.0, 'c_max': 1.0, 'v_abs_max': 0.5}
    d.update(kw)
    return d


def test_the_guard_reports_each_module_once_and_names_why():
    guard = DivergenceGuard(['innate', 'view', 'place'], [0.9, 0.95, 0.99])
    assert guard.bound('view') == pytest.approx(FACTOR / 0.05)
    assert guard.check(1, {'innate': _diag(), 'view': _diag(), 'place': _diag()}) == []
    new = guard.check(2, {'innate': _diag(), 'view': _diag(v_abs_max=250.0),
                          'place': _diag(c_max=math.inf)})
    assert [(d.module, d.episode) for d in new] == [('view', 2), ('place', 2)]
    assert '250' in new[0].reason and 'overflowed' in new[1].reason
    assert 'docs/results.md#divergence' in new[0].message()
    # once: the same modules again are not reported; another one is
    again = guard.check(3, {'innate': _diag(diverged=1.0), 'view': _diag(v_abs_max=1e9),
                            'place': _diag(v_abs_max=math.nan)})
    assert [(d.module, d.reason) for d in again] == [
        ('innate', 'its update was not finite (not applied)')]


def test_the_bound_follows_the_largest_reward_seen():
    guard = DivergenceGuard(['view'], [0.9])
    assert guard.check(1, {'view': _diag(v_abs_max=90.0)}, rewards=[1.0, -0.1]) == []
    assert guard.bound('view') == pytest.approx(100.0)
    assert guard.check(2, {'view': _diag(v_abs_max=150.0)}, rewards=[2.0]) == []
    assert guard.check(3, {'view': _diag(v_abs_max=201.0)}) != []
    # a module that did not decide in the episode (no steps) says nothing
    assert DivergenceGuard(['view'], [0.9]).check(
        1, {'view': _diag(n_steps=0.0, v_abs_max=math.inf)}) == []


def test_a_row_carries_the_report():
    row = {'diverged': 'view+place', 'diverged_why': 'a; b'}
    assert Divergence.from_row(row, 7) == [Divergence('view', 7, 'a'),
                                           Divergence('place', 7, 'b')]
    assert Divergence.from_row({'diverged': ''}, 1) == []
    assert Divergence.from_row({}, 1) == []


def _run(preset: str, tmp_path, episodes: int = 40):
    spec = JobSpec(index=0, label=preset, condition='async',
                   overrides=preset_overrides(preset), sim_overrides={}, seed=0,
                   episodes=episodes, eval_episodes=0, arena=None, run_dir=str(tmp_path),
                   block=10, preset=preset)
    notes = []
    result = run_job(spec, progress=lambda n, note: notes.append(note))
    return result, [n for n in notes if n.startswith('WARNING')]


def test_the_guard_fires_on_a_literal_paper_run_and_stays_silent_on_improved(tmp_path):
    """Async, seed 0, 40 episodes: under the paper's rules the view module's value leaves
    every possible return (|V| in the thousands by episode 20); under improved no module's
    does."""
    paper, warned = _run('paper', tmp_path)
    assert 'view' in paper.diverged and paper.diverged['view'] <= 40
    assert warned and 'module view diverged at episode' in warned[0]
    rows = [r for r in paper.episodes if r['diverged']]
    assert [r['episode'] + 1 for r in rows if 'view' in r['diverged']] == [paper.diverged['view']]
    improved, warned = _run('improved', tmp_path)
    assert improved.diverged == {} and warned == []
    assert all(r['diverged'] == '' for r in improved.episodes)
    assert max(abs(r['v_view']) for r in improved.episodes) < 10.0


def test_the_run_folder_reports_it_in_its_summary_and_curve(tmp_path):
    import csv
    paper, _ = _run('paper', tmp_path)
    rows = paper.table_episodes()
    with open(tmp_path / 'episodes.csv', 'w', newline='') as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    with open(tmp_path / 'episodes.csv', newline='') as fh:
        read = list(csv.DictReader(fh))
    assert [(d.module, d.episode) for d in divergences(read)] == sorted(
        paper.diverged.items(), key=lambda kv: kv[1])
    text = summary(tmp_path, 10, 'paper')
    assert text.startswith('summary (paper preset)')
    assert f'module view diverged at episode {paper.diverged["view"]}' in text
    csv_path, png = write_curve(tmp_path, 10, 'paper')
    assert png.is_file() and png.stat().st_size > 0


def test_both_commands_default_to_the_preset_that_learns():
    assert DEFAULT_PRESET == 'improved'
    parser = build_parser()
    run = parser.parse_args(['run'])
    experiment = parser.parse_args(['experiment', '--out', 'x'])
    assert run.preset == experiment.preset == 'improved'
    assert parser.parse_args(['run', '--preset', 'paper']).preset == 'paper'
    assert parser.parse_args(['experiment', '--out', 'x', '--preset', 'paper']).preset == 'paper'
