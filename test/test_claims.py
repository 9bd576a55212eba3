"""``python -m clis_app.experiments.claims``: the paper's claims from a folder of runs, with 95%
t-intervals, against figures computed by hand."""

from __future__ import annotations

from dataclasses import asdict
import json
import math

from clis_app.experiments.claims import claims, load_runs, main, mean_ci
from clis_app.experiments.runner import JobResult
import numpy as np
import pytest


def run(label, seed, rates, shares=None, evals=()):
    """A run with evaluation points every 100 episodes at the given success rates."""
    modules = ['innate', 'view', 'place'] if label in ('sync', 'async') else [label]
    sh = shares or {m: 1.0 / len(modules) for m in modules}
    episodes = [{'episode': k, **{f'share_{m}': sh[m] for m in modules}} for k in range(1000)]
    curve = [{'episode': 100 * k, 'reached': int(round(10 * p)), 'n': 10}
             for k, p in enumerate(rates)]
    return JobResult(spec={'label': label, 'seed': seed, 'overrides': {}}, modules=modules,
                     block=50, episodes=episodes, evals=list(evals), place_map=None, arena={},
                     seconds=1.0, eval_curve=curve)


def test_mean_ci_is_the_t_interval_and_none_below_three():
    m, h = mean_ci([1.0, 2.0, 3.0])
    assert m == 2.0 and h == pytest.approx(4.302653 * 1.0 / math.sqrt(3), rel=1e-5)
    assert math.isnan(mean_ci([1.0, 2.0])[1])


def test_claims_against_hand_figures(tmp_path):
    flat = [0.6] * 11
    rising = [0.0, 0.0, 0.1, 0.3, 0.6, 0.6, 0.7, 0.8, 0.8, 0.9, 0.9]
    runs = {'innate': [run('innate', s, flat) for s in range(3)],
            'view': [run('view', s, rising) for s in range(3)],
            'async': [run('async', s, [max(0.0, r - 0.2 - 0.1 * s) for r in rising],
                          {'innate': 0.2, 'view': 0.5, 'place': 0.3})
                      for s in range(3)]}
    rows = {a: (b, c) for a, b, c in claims(runs)}
    assert rows['Innate is flat (end - early)'] == ('0.0 ± 0.0%', 'yes')
    # View reaches 60% at episode 400 in every seed
    assert rows["View reaches Innate's level at episode (paper: ~300)"][0] == '400.0 ± 0.0'
    # end window = points 800, 900, 1000: (0.8 + 0.9 + 0.9) / 3 - 0.6 = 0.2667
    m, c = rows['View never exceeds Innate (end, View - Innate)']
    assert m == '26.7 ± 0.0%' and c == 'no (View above)'
    assert rows['Async ends best (end, async - best single = view)'][1] == 'no'
    mid = rows['Fig. 3c: async shares, episodes 300-600 (mid)'][0]
    assert mid == 'innate 20.0 ± 0.0%, view 50.0 ± 0.0%, place 30.0 ± 0.0%'
    (tmp_path / 'runs').mkdir()
    for lab, rs in runs.items():
        for r in rs:
            (tmp_path / 'runs' / f'{lab}__s{r.spec["seed"]}.json').write_text(
                json.dumps(asdict(r)))
    assert sorted(load_runs(tmp_path)) == ['async', 'innate', 'view']
    assert main([str(tmp_path)]) == 0
    assert main([str(tmp_path / 'nothing')]) == 2


def test_a_preset_folder_is_read_and_a_mixed_one_refused(tmp_path, capsys):
    flat = [0.6] * 11
    (tmp_path / 'runs').mkdir()
    for s in range(3):
        for label, preset in (('improved:innate', 'improved'),
                              ('improved:async@learner.imitation=1.0', 'improved')):
            r = run('innate', s, flat)
            r.spec.update(label=label, preset=preset, overrides={'common.beta': 5.0})
            (tmp_path / 'runs' / f'{label}__s{s}.json').write_text(json.dumps(asdict(r)))
    runs = load_runs(tmp_path)
    assert sorted(runs) == ['innate'] and len(runs['innate']) == 3    # the @ row is not
    assert main([str(tmp_path)]) == 0
    assert 'Preset `improved`, arena `arena.yaml`' in capsys.readouterr().out
    r = run('view', 0, flat)
    (tmp_path / 'runs' / 'view__s0.json').write_text(json.dumps(asdict(r)))   # paper
    with pytest.raises(ValueError, match='presets improved, paper'):
        load_runs(tmp_path)
    assert main([str(tmp_path)]) == 2


def test_async_is_judged_against_every_single_module():
    flat, low = [0.6] * 11, [0.1] * 11
    runs = {'innate': [run('innate', s, flat) for s in range(3)],
            'view': [run('view', s, low) for s in range(3)],
            'async': [run('async', s, [0.7] * 11) for s in range(3)]}
    rows = {a: (b, c) for a, b, c in claims(runs)}
    assert rows['Async ends best (end, async - best single = innate)'][1] == 'yes'
    assert rows['Async ends above view (end, async - view)'] == ('60.0 ± 0.0%', 'yes')
    assert np.isfinite(mean_ci([0.1, 0.2, 0.4])[1])
