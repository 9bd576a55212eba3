"""clis compare: block success rates with 95% bands, from episodes.csv files."""

from __future__ import annotations

import csv

from clis_app.cli import main
from clis_app.experiments.compare import compare, load_curves
import numpy as np


def write_runs(folder, condition, probs, seed0=0, n=100):
    folder.mkdir(parents=True)
    rng = np.random.default_rng(seed0)
    with open(folder / 'episodes.csv', 'w', newline='') as fh:
        w = csv.DictWriter(fh, ['condition', 'seed', 'phase', 'episode', 'reached'])
        w.writeheader()
        for s, p in enumerate(probs):
            for e in range(n):
                w.writerow({'condition': condition, 'seed': s + seed0, 'phase': 'train',
                            'episode': e, 'reached': int(rng.random() < p * (e >= n // 2))})
            w.writerow({'condition': 'other', 'seed': s, 'phase': 'train', 'episode': 0,
                        'reached': 1})


def test_compare_tells_alike_from_different(tmp_path, capsys):
    write_runs(tmp_path / 'a', 'async', [0.8, 0.85, 0.75])
    write_runs(tmp_path / 'b', 'async', [0.8, 0.7, 0.85], seed0=10)
    write_runs(tmp_path / 'c', 'async', [0.1, 0.05, 0.15], seed0=20)
    a, b, c = (load_curves([tmp_path / k], 'async') for k in 'abc')
    assert len(a) == 3 and all(len(x) == 100 for x in a.values())
    same = compare(a, b, block=50)
    assert [r['overlap'] for r in same] == [1.0, 1.0]
    assert same[0]['a'] == same[0]['b'] == 0.0              # nobody reaches in the first half
    diff = compare(a, c, block=50)
    assert diff[1]['overlap'] == 0.0 and diff[1]['p'] < 0.01
    assert main(['compare', '--a', str(tmp_path / 'a'), '--b', str(tmp_path / 'c'),
                 '--condition', 'async', '--png', str(tmp_path / 'x.png')]) == 0
    assert '| 51-100 |' in capsys.readouterr().out and (tmp_path / 'x.png').stat().st_size
    assert main(['compare', '--a', str(tmp_path / 'a'), '--b', str(tmp_path / 'c'),
                 '--condition', 'view']) == 2
