"""``clis compare``: do two sets of runs learn alike? Success per block with 95% bands.

Reads the ``episodes.csv`` of each folder (a ``clis run`` output: one run; a ``clis experiment``
output: its runs), keeps the learning episodes of one condition, and compares set A with set B
block by block (``--block`` episodes): the fraction of episodes that reached the destination,
mean over runs (seeds) and the half-width of its 95% t-interval (:func:`figures.band`), whether
the two intervals overlap, and Welch's t-test. Made for the graph-vs-headless equivalence check:

    clis compare --a results/equiv/graph-async-seed* --b results/equiv/headless \\
        --condition async --png results/equiv/async.png
"""

from __future__ import annotations

import argparse
from collections import defaultdict
import csv
from pathlib import Path
import sys

import numpy as np
from scipy import stats

__all__ = ['load_curves', 'compare', 'register']


def load_curves(folders: list[Path], condition: str, column: str = 'reached'
                ) -> dict[str, np.ndarray]:
    """``column`` of the learning episodes of ``condition``, one array per run (in episode
    order), keyed ``folder:seed``."""
    curves: dict[str, list[tuple[int, float]]] = defaultdict(list)
    for folder in folders:
        path = folder / 'episodes.csv' if folder.is_dir() else folder
        with open(path, newline='') as fh:
            for row in csv.DictReader(fh):
                if row.get('condition', condition) != condition \
                        or row.get('phase', 'train') != 'train':
                    continue
                curves[f'{folder}:{row.get("seed", "")}'].append(
                    (int(row['episode']), float(row[column])))
    return {k: np.array([v for _, v in sorted(rows)]) for k, rows in curves.items()}


def compare(a: dict[str, np.ndarray], b: dict[str, np.ndarray], block: int
            ) -> list[dict[str, float]]:
    """Per block of ``block`` episodes (over the episodes every run has): mean and 95%
    half-width of A and B, overlap of the intervals, Welch's p."""
    from clis_app.experiments.figures import band
    n = min(len(c) for c in [*a.values(), *b.values()])
    n_blocks = n // block
    if n_blocks == 0:
        raise ValueError(f'the shortest run has {n} episodes, less than one block of {block}')

    def blocks(curves: dict[str, np.ndarray]) -> np.ndarray:    # (runs, blocks)
        return np.array([c[:n_blocks * block].reshape(n_blocks, block).mean(1)
                         for c in curves.values()])
    xa, xb = blocks(a), blocks(b)
    (ma, ha), (mb, hb) = band(xa), band(xb)
    rows = []
    for k in range(n_blocks):
        p = stats.ttest_ind(xa[:, k], xb[:, k], equal_var=False).pvalue \
            if len(xa) > 1 and len(xb) > 1 else float('nan')
        rows.append({'from': k * block + 1, 'to': (k + 1) * block, 'a': ma[k], 'a_half': ha[k],
                     'b': mb[k], 'b_half': hb[k],
                     'overlap': float(max(ma[k] - ha[k], mb[k] - hb[k])
                                      <= min(ma[k] + ha[k], mb[k] + hb[k]))
                     if np.isfinite([ha[k], hb[k]]).all() else float('nan'),
                     'p': float(p)})
    return rows


def table(rows: list[dict[str, float]], a_name: str, b_name: str, n_a: int, n_b: int) -> str:
    out = [f'| episodes | {a_name} ({n_a} runs) | {b_name} ({n_b} runs) | 95% bands overlap '
           "| Welch's p |", '|---|---|---|---|---|']
    for r in rows:
        overlap = ('n/a (fewer than 3 runs)' if not np.isfinite(r['overlap'])
                   else 'yes' if r['overlap'] else 'NO')
        out.append(f'| {r["from"]}-{r["to"]} | {_pm(r["a"], r["a_half"])} | '
                   f'{_pm(r["b"], r["b_half"])} | {overlap} | {r["p"]:.2f} |')
    return '\n'.join(out)


def _pm(mean: float, half: float) -> str:
    return f'{mean:.2f} ± {half:.2f}' if np.isfinite(half) else f'{mean:.2f}'


def plot(rows: list[dict[str, float]], a_name: str, b_name: str, title: str,
         path: Path) -> None:
    from clis_app.experiments.figures import _save, plt
    x = np.array([(r['from'] + r['to']) / 2 for r in rows])
    fig, ax = plt.subplots(figsize=(5, 3.2))
    for key, name, colour in (('a', a_name, 'tab:blue'), ('b', b_name, 'tab:orange')):
        m = np.array([r[key] for r in rows])
        h = np.array([r[f'{key}_half'] for r in rows])
        ax.plot(x, m, 'o-', color=colour, label=name)
        if np.isfinite(h).all():
            ax.fill_between(x, m - h, m + h, color=colour, alpha=0.2)
    ax.set_xlabel('episode')
    ax.set_ylabel('fraction reached (per block)')
    ax.set_ylim(-0.05, 1.05)
    ax.set_title(title)
    ax.legend()
    _save(fig, path)


def _error(message: str) -> int:
    print(f'clis compare: {" ".join(str(message).split())}', file=sys.stderr)
    return 2


def _main(args: argparse.Namespace) -> int:
    if args.block < 1:
        return _error(f'--block must be >= 1 (got {args.block})')
    for flag, folders in (('--a', args.a), ('--b', args.b)):
        for folder in folders:
            if not (folder / 'episodes.csv' if folder.is_dir() else folder).is_file():
                return _error(f'{flag} {folder}: no episodes.csv there')
    if args.png is not None and not args.png.parent.is_dir():
        return _error(f'--png {args.png}: no folder {args.png.parent}')
    try:
        a = load_curves(args.a, args.condition)
        b = load_curves(args.b, args.condition)
    except (KeyError, ValueError, UnicodeDecodeError) as exc:
        return _error(f'cannot read the episodes ({type(exc).__name__}: {exc})')
    if not a or not b:
        return _error(f'--condition {args.condition}: no learning episodes of it in '
                      f'{"--a" if not a else "--b"}')
    try:
        rows = compare(a, b, args.block)
    except ValueError as exc:
        return _error(f'--block {args.block}: {exc}')
    print(f'{args.condition}: fraction of episodes that reached the destination, mean ± 95% '
          f'half-width over runs')
    print(table(rows, args.a_name, args.b_name, len(a), len(b)))
    if args.png:
        plot(rows, args.a_name, args.b_name, args.condition, args.png)
        print(f'figure: {args.png}')
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    from clis_app.cli.help import HelpFormatter
    p = sub.add_parser('compare', help='compare two sets of runs block by block (95%% bands)',
                       description=__doc__, formatter_class=HelpFormatter)
    p.add_argument('--a', type=Path, nargs='+', required=True, help='folders of set A')
    p.add_argument('--b', type=Path, nargs='+', required=True, help='folders of set B')
    p.add_argument('--condition', required=True, help='condition to compare (async, view...)')
    p.add_argument('--block', type=int, default=50, help='episodes per block')
    p.add_argument('--a-name', default='graph', help='name of set A in the table')
    p.add_argument('--b-name', default='headless', help='name of set B in the table')
    p.add_argument('--png', type=Path, help='also draw both bands into this PNG')
    p.set_defaults(func=_main)
