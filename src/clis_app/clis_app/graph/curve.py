"""What a ``clis run`` leaves in its folder at the end: the learning curve and a summary.

From ``OUT/episodes.csv`` (one row per learned episode, written by the learner): ``curve.csv``,
``curve.png`` and ``selection.png`` (:func:`write_curve`), and a few lines on the run
(:func:`summary`).
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

from clis_learner.core.guard import Divergence
import numpy as np

from clis_app import files

__all__ = ['divergences', 'summary', 'write_curve']


def write_curve(out: Path, block: int, preset: str = '') -> tuple[Path, Path] | None:
    """``OUT/curve.csv`` and ``OUT/curve.png`` from ``OUT/episodes.csv`` (learned episodes):
    successes per block and the share of time each module acted, the divergences the guard
    reported marked; the title names ``preset``. None without episodes."""
    from clis_app.experiments import figures
    from clis_app.experiments.runner import JobResult
    path = out / 'episodes.csv'
    if not path.is_file():
        return None
    with open(path, newline='') as fh:
        rows = [_numbers(r) for r in csv.DictReader(fh)]
    if not rows:
        return None
    names = [k[len('share_'):] for k in rows[0] if k.startswith('share_')]
    block = max(1, min(block, len(rows)))
    condition = str(rows[0].get('condition', 'graph'))
    label = f'{preset}:{condition}' if preset else condition
    result = JobResult(spec={'label': label, 'preset': preset}, modules=names,
                       block=block, episodes=rows, evals=[], place_map=None, arena={},
                       seconds=0.0)
    successes = result.success_curve()
    shares = result.selection_shares()
    csv_path = out / 'curve.csv'
    files.write_csv(csv_path, [[(k + 1) * block, int(s), *[round(float(x), 4) for x in shares[k]]]
                               for k, s in enumerate(successes)],
                    ['episodes', f'successes_per_{block}', *[f'share_{n}' for n in names]])
    png = out / 'curve.png'
    figures.run_curve(result, png)
    if len(names) > 1:
        figures.run_selection(result, out / 'selection.png')
    return csv_path, png


def _numbers(row: dict[str, str]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in row.items():
        try:
            out[k] = float(v)
        except (TypeError, ValueError):
            out[k] = v
    return out


def divergences(rows: list[dict[str, Any]]) -> list[Divergence]:
    """What the divergence guard reported in the rows of ``episodes.csv``, in order (the
    episode: the n-th learned one, as the guard counts)."""
    out = []
    learned = 0
    for r in rows:
        learned += str(r.get('learned', '1')) in ('1', '1.0')
        out += Divergence.from_row(r, learned)
    return out


def summary(out: Path, block: int, preset: str = '') -> str:
    """A few lines on the run from ``OUT/episodes.csv``: successes early and late, who acted,
    and what the divergence guard reported."""
    with open(out / 'episodes.csv', newline='') as fh:
        rows = list(csv.DictReader(fh))
    n = len(rows)
    k = max(1, min(block, n // 2 or 1))
    first = sum(int(float(r['reached'])) for r in rows[:k])
    last = sum(int(float(r['reached'])) for r in rows[-k:])
    names = [c[len('share_'):] for c in rows[0] if c.startswith('share_')]
    shares = ', '.join(f'{m} {np.mean([float(r[f"share_{m}"]) for r in rows[-k:]]):.0%}'
                       for m in names)
    lost = sum(r.get('complete', '1') == '0' for r in rows)
    gone = ''.join(f'\nWARNING: {d.message()}' for d in divergences(rows))
    return (f'summary{f" ({preset} preset)" if preset else ""}: {n} episodes learned; '
            f'reached {first}/{k} in the first {k}, '
            f'{last}/{k} in the last {k}; who acted in the last {k}: {shares}'
            + (f'; WARNING: {lost} episodes lost reward messages (see logs/learner.log)'
               if lost else '') + gone)
