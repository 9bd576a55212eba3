"""``python -m clis_app.experiments.divergence``: the growth of the importance product, from the
learner's per-episode diagnostics (docs/results.md, the divergence of (8))."""

from __future__ import annotations

import csv
import math

from clis_app.experiments.divergence import divergence_rows, main


def write(path, rows):
    with open(path, 'w', newline='') as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def row(seed, episode, behaviour, c_max_view, c_final_view, grow_view, v_view):
    return {'label': 'async', 'seed': seed, 'phase': 'train', 'episode': episode,
            'behaviour': behaviour, 'c_max_innate': 1.0, 'c_final_innate': 1.0,
            'grow_share_innate': 0.0, 'v_innate': 1.0,
            'c_max_view': c_max_view, 'c_final_view': c_final_view,
            'grow_share_view': grow_view, 'v_view': v_view}


def test_summary_of_the_off_policy_episodes_against_hand_figures(tmp_path, capsys):
    rows = [row(0, 1, 'innate', 100.0, 1e-3, 0.5, 0.1),
            row(0, 2, 'innate', 0.1, 1e-5, 0.1, 20.0),      # diverged from episode 2
            row(0, 3, 'view', 1e9, 1.0, 0.9, 50.0),          # on-policy for view: left out
            row(1, 1, 'innate', 10.0, 1e-1, 0.3, -0.5),
            row(1, 2, 'innate', 1.0, 1e-2, 0.2, 0.2)]
    (view,) = [r for r in divergence_rows(rows) if r['module'] == 'view']
    assert view['episodes'] == 4
    assert view['log_c_max_median'] == 0.5            # median of 2, -1, 1, 0
    assert view['log_c_final_median'] == -2.5          # median of -3, -5, -1, -2
    assert math.isclose(view['grow_share_mean'], 0.275)
    assert view['rose_above_1'] == 0.5                 # c_max > 1 in 2 of 4
    assert view['onset_median'] == 2.0 and view['seeds_diverged'] == '1/2'
    write(tmp_path / 'episodes.csv', rows)
    assert main([str(tmp_path), '--png', str(tmp_path / 'c.png')]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith('| condition | target |') and len(out) == 2 + 2
    assert (tmp_path / 'c.png').stat().st_size > 0
    assert main([str(tmp_path / 'missing')]) == 2
