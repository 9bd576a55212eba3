"""``python -m clis_app.experiments.divergence OUT``: how the importance product of (8) and
(9) grows.

The product ``c_i <- rho~_i c_i`` of (8)(9) multiplies one truncated ratio (7) per decision of
the target module i. Even when each ratio is near 1 the product random-walks in log space, and
the trace of (8), ``e_i <- lambda_i gamma_i rho~_i e_i + c_i b_i``, grows geometrically over the
stretches where ``gamma_i rho~_i > 1``. This reads the learner's per-episode diagnostics of a
``clis experiment`` folder (``episodes.csv``: ``c_final``, ``c_max``, ``grow_share`` and
``v_start`` per module) and prints, per condition and target module, over the learning
episodes that another module played (off-policy for the target):

* the median and 90th percentile of ``log10 c_max`` (how far the product rose) and the median
  ``log10 c_final`` (where it ended);
* the mean share of steps with ``gamma_i rho~ > 1`` and the share of episodes in which the
  product rose above 1 at some step;
* the first episode at which ``|V_i(x_0)| > 10`` (a return is at most 1), median over seeds,
  and how many seeds got there: the onset of the divergence of (8).

``--png FILE`` draws ``log10 c_max`` per episode (block medians) for every condition with
several modules.
"""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path
import sys

import numpy as np

from clis_app.experiments.runner import JobResult

__all__ = ['divergence_rows', 'main']

#: |V_i(x_0)| beyond this is divergence: a return is at most 1 (one goal reward).
V_DIVERGED = 10.0


def _float(v: str) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def load_train_rows(out: Path) -> list[dict[str, str]]:
    """The learning episodes of ``OUT/episodes.csv``, or of the runs finished so far
    (``OUT/runs/*.json``) while the experiment is still running."""
    path = Path(out) / 'episodes.csv'
    if path.is_file():
        with open(path, newline='') as f:
            return [r for r in csv.DictReader(f) if r.get('phase', 'train') == 'train']
    runs = sorted(Path(out).glob('runs/*.json'))
    if not runs:
        raise FileNotFoundError(f'{path}: no such file, and no runs/*.json (a clis experiment '
                                'folder?)')
    return [{k: str(v) for k, v in e.items()} for p in runs
            for e in JobResult.load(p).table_episodes()]


def divergence_rows(rows: list[dict[str, str]]) -> list[dict[str, float | str]]:
    """One summary per (condition label, target module) with off-policy episodes."""
    labels = sorted({r['label'] for r in rows}, key=[r['label'] for r in rows].index)
    out = []
    for label in labels:
        mine = [r for r in rows if r['label'] == label]
        modules = [k[len('c_max_'):] for k in mine[0] if k.startswith('c_max_')]
        for m in modules:
            off = [r for r in mine if r.get('behaviour') != m
                   and math.isfinite(_float(r.get(f'c_max_{m}')))]
            if not off:
                continue
            with np.errstate(divide='ignore'):
                c_max = np.log10(np.array([_float(r[f'c_max_{m}']) for r in off]))
                c_fin = np.log10(np.array([_float(r[f'c_final_{m}']) for r in off]))
            grow = np.array([_float(r.get(f'grow_share_{m}')) for r in off])
            onsets = []
            seeds = sorted({r['seed'] for r in mine})
            for s in seeds:
                ep = [int(r['episode']) for r in mine if r['seed'] == s
                      and abs(_float(r.get(f'v_{m}'))) > V_DIVERGED]
                if ep:
                    onsets.append(min(ep))
            out.append({
                'condition': label, 'module': m, 'episodes': len(off),
                'log_c_max_median': float(np.nanmedian(c_max)),
                'log_c_max_p90': float(np.nanpercentile(c_max, 90)),
                'log_c_final_median': float(np.nanmedian(np.maximum(c_fin, -300.0))),
                'grow_share_mean': float(np.nanmean(grow)),
                'rose_above_1': float(np.mean(c_max > 0.0)),
                'onset_median': float(np.median(onsets)) if onsets else math.nan,
                'seeds_diverged': f'{len(onsets)}/{len(seeds)}'})
    return out


def markdown(table: list[dict[str, float | str]]) -> str:
    """The summaries as a Markdown table."""
    head = ('| condition | target | off-policy episodes | log10 c_max median (p90) | '
            'log10 c_final median | steps with gamma_i rho > 1 | episodes with c > 1 | '
            '\\|V\\| > 10 from episode (seeds) |')
    lines = [head, '|' + '---|' * 8]
    for r in table:
        onset = ('never' if math.isnan(r['onset_median'])
                 else f"{r['onset_median']:.0f} ({r['seeds_diverged']})")
        lines.append(f"| {r['condition']} | {r['module']} | {r['episodes']} | "
                     f"{r['log_c_max_median']:.1f} ({r['log_c_max_p90']:.1f}) | "
                     f"{r['log_c_final_median']:.1f} | {100 * r['grow_share_mean']:.0f}% | "
                     f"{100 * r['rose_above_1']:.0f}% | {onset} |")
    return '\n'.join(lines)


def plot(rows: list[dict[str, str]], path: Path, block: int = 50) -> None:
    """``log10 c_max`` of the off-policy episodes per block (median over seeds and episodes),
    one panel per condition with several modules."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    def n_modules(label: str) -> int:          # columns with values (a merged CSV has all)
        first = next(r for r in rows if r['label'] == label)
        return sum(k.startswith('c_max_') and v not in ('', 'nan', None)
                   for k, v in first.items())

    labels = [lb for lb in dict.fromkeys(r['label'] for r in rows) if n_modules(lb) > 1]
    if not labels:
        raise ValueError('no condition with several modules to draw')
    fig, axes = plt.subplots(1, len(labels), figsize=(5 * len(labels), 3.6), squeeze=False)
    for ax, label in zip(axes[0], labels):
        mine = [r for r in rows if r['label'] == label]
        for m in [k[len('c_max_'):] for k, v in mine[0].items()
                  if k.startswith('c_max_') and v not in ('', 'nan', None)]:
            pts = [(int(r['episode']), _float(r[f'c_max_{m}'])) for r in mine
                   if r.get('behaviour') != m and _float(r[f'c_max_{m}']) > 0.0]
            if not pts:
                continue
            ep, c = np.array(pts).T
            b = (ep // block).astype(int)
            xs = [block * (k + 0.5) for k in np.unique(b)]
            ys = [np.median(np.log10(c[b == k])) for k in np.unique(b)]
            ax.plot(xs, ys, marker='o', ms=3, label=f'target {m}')
        ax.axhline(0.0, color='k', lw=0.5)
        ax.set_title(f'{label}: off-policy episodes')
        ax.set_xlabel('episode')
        ax.set_ylabel('log10 max_l c_l (median per block)')
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(args: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog='python -m clis_app.experiments.divergence',
                                description=__doc__.split('\n\n')[0])
    p.add_argument('out', type=Path, help='a clis experiment folder (its episodes.csv)')
    p.add_argument('--png', type=Path, help='also draw log10 c_max per block to this file')
    a = p.parse_args(args)
    try:
        rows = load_train_rows(a.out)
    except FileNotFoundError as e:
        print(f'divergence: {e}', file=sys.stderr)
        return 2
    print(markdown(divergence_rows(rows)))
    if a.png:
        plot(rows, a.png)
    return 0


if __name__ == '__main__':
    sys.exit(main())
