"""``python -m clis_app.experiments.claims OUT``: the paper's Fig. 3a/3b/3c/5 claims, measured.

Reads the runs of a ``clis experiment`` folder (``OUT/runs/*.json``, one per condition and
seed; the conditions ``innate``, ``view``, ``place``, ``sync`` and ``async`` without ``@``
overrides, in one preset: ``paper`` or e.g. ``improved``, whose labels are ``improved:view``...)
and prints one Markdown table: each claim of the paper's Sec. IV, the number measured here as
the mean over seeds with its 95% t-interval, and whether it holds (the interval on the right
side of the claim). The Fig. 3a numbers are the A-E evaluation (learning off, every
``--eval-every`` learning episodes: the paper's Fig. 2 caption), as a success rate.

Windows: "early" is the evaluation points up to episode 200, "end" those from the last 200
episodes on (the last point included). Innate's level is Innate's mean over all its points.
"Reaches Innate's level at" is, per seed, the first evaluation point at or above that level
(the run's length + the evaluation interval where it never does).

With fewer than 3 seeds no interval is given (a t-interval with 1 degree of freedom spans
almost any axis); the table says so.
"""

from __future__ import annotations

import argparse
from collections import defaultdict
import math
from pathlib import Path
import sys

import numpy as np
from scipy import stats

from clis_app.experiments.runner import JobResult

__all__ = ['load_runs', 'mean_ci', 'claims', 'main']

PAPER = ('innate', 'view', 'place', 'sync', 'async')
#: Episodes of the "early" and "end" windows.
WINDOW = 200


def load_runs(out: Path) -> dict[str, list[JobResult]]:
    """``{condition: [run per seed]}`` of the paper's five conditions without ``@`` overrides
    (a preset's own changes, e.g. ``improved:view``, are part of the condition).

    Raises
    ------
    ValueError
        The folder mixes presets: its claims would compare runs of different rules.
    """
    runs: dict[str, list[JobResult]] = defaultdict(list)
    presets = set()
    for path in sorted(Path(out, 'runs').glob('*.json')):
        r = JobResult.load(path)
        label = r.spec['label'].split(':')[-1]
        if label in PAPER:
            runs[label].append(r)
            presets.add(r.spec.get('preset') or 'paper')
    if len(presets) > 1:
        raise ValueError(f'{out}: runs of presets {", ".join(sorted(presets))}: one per folder')
    for rs in runs.values():
        rs.sort(key=lambda r: r.spec['seed'])
    return dict(runs)


def mean_ci(x) -> tuple[float, float]:
    """Mean and the half-width of its 95% t-interval (NaN below 3 values)."""
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return math.nan, math.nan
    if x.size < 3:
        return float(x.mean()), math.nan
    return float(x.mean()), float(stats.t.ppf(0.975, x.size - 1) * x.std(ddof=1)
                                  / math.sqrt(x.size))


def _fmt(m: float, h: float, pct: bool = False, unit: str = '') -> str:
    if math.isnan(m):
        return 'n/a'
    k = 100.0 if pct else 1.0
    s = f'{k * m:.1f}'
    return (s if math.isnan(h) else s + f' ± {k * h:.1f}') + ('%' if pct else unit)


def _rate(r: JobResult) -> tuple[np.ndarray, np.ndarray]:
    """Evaluation points and success rates of one run."""
    return (np.array(r.eval_points(), float),
            np.array([p['reached'] / p['n'] for p in r.eval_curve], float))


def window(r: JobResult, which: str) -> float:
    """Mean evaluated success rate of the early or end window."""
    pts, rate = _rate(r)
    if not len(pts):
        return math.nan
    last = pts.max()
    sel = pts <= WINDOW if which == 'early' else pts >= last - WINDOW
    return float(rate[sel].mean())


def first_at(r: JobResult, level: float) -> float:
    """First evaluation point at or above ``level`` (NaN if never)."""
    pts, rate = _rate(r)
    hit = np.flatnonzero(rate >= level - 1e-12)
    return float(pts[hit[0]]) if hit.size else math.nan


def shares(r: JobResult, lo: int, hi: int) -> np.ndarray:
    """Mean share of the time each module acted over learning episodes ``[lo, hi)``."""
    rows = r.episodes[lo:hi]
    return np.array([np.mean([e.get(f'share_{m}', np.nan) for e in rows]) for m in r.modules])


def eval_time(r: JobResult, start: str) -> float:
    """Mean time to the destination [s] from ``start`` after learning (timeouts count)."""
    d = [e['duration'] for e in r.evals if e['start'] == start]
    return float(np.mean(d)) if d else math.nan


def _paired(a: list[JobResult], b: list[JobResult], fa, fb=None) -> np.ndarray:
    """``fa(a_s) - fb(b_s)`` over the seeds both have."""
    fb = fa if fb is None else fb
    bs = {r.spec['seed']: r for r in b}
    return np.array([fa(r) - fb(bs[r.spec['seed']]) for r in a if r.spec['seed'] in bs])


def claims(runs: dict[str, list[JobResult]]) -> list[tuple[str, str, str]]:
    """``(claim, measured, holds)`` rows; conditions missing from ``runs`` are skipped."""
    rows: list[tuple[str, str, str]] = []

    def verdict(m: float, h: float, above: bool) -> str:
        if math.isnan(m):
            return 'n/a'
        if math.isnan(h):
            return 'no interval (< 3 seeds)'
        lo, hi = m - h, m + h
        if above:
            return 'yes' if lo > 0 else ('no' if hi < 0 else 'not resolved (CI spans 0)')
        return 'yes' if hi < 0 else ('no' if lo > 0 else 'not resolved (CI spans 0)')

    def no_difference(m: float, h: float) -> str:
        if math.isnan(m) or math.isnan(h):
            return 'n/a' if math.isnan(m) else 'no interval (< 3 seeds)'
        return 'yes' if m - h <= 0.0 <= m + h else 'no'

    inn = runs.get('innate', [])
    level = float(np.nanmean([_rate(r)[1].mean() for r in inn])) if inn else math.nan
    if inn:
        m, h = mean_ci([window(r, 'end') - window(r, 'early') for r in inn])
        rows.append(('Innate is flat (end - early)', _fmt(m, h, pct=True), no_difference(m, h)))
        rows.append(("Innate's level (all points)", _fmt(*mean_ci(
            [_rate(r)[1].mean() for r in inn]), pct=True), '-'))
    singles = [c for c in ('innate', 'view', 'place') if runs.get(c)]
    for c in ('view', 'place', 'sync', 'async'):
        rs = runs.get(c, [])
        if not rs:
            continue
        rows.append((f'{c.capitalize()}: early -> end', ' -> '.join(
            _fmt(*mean_ci([window(r, w) for r in rs]), pct=True) for w in ('early', 'end')),
            '-'))
        if inn:
            at = np.array([first_at(r, level) for r in rs])
            never = int(np.isnan(at).sum())
            target = {'view': '~300', 'place': '(slower than View)', 'sync': '~150',
                      'async': '~150'}[c]
            rows.append((f"{c.capitalize()} reaches Innate's level at episode (paper: {target})",
                         (_fmt(*mean_ci(at)) if never < len(at) else 'never')
                         + (f' (never in {never} of {len(at)} seeds)' if 0 < never else ''),
                         '-'))
    if runs.get('view') and inn:
        m, h = mean_ci(_paired(runs['view'], inn, lambda r: window(r, 'end')))
        above = verdict(m, h, True)
        rows.append(('View never exceeds Innate (end, View - Innate)', _fmt(m, h, pct=True),
                     'no (View above)' if above == 'yes' else
                     above if above.startswith(('n/a', 'no interval')) else 'yes'))
    if runs.get('place'):
        m, h = mean_ci([window(r, 'end') - window(r, 'early') for r in runs['place']])
        rows.append(('Place improves (end - early)', _fmt(m, h, pct=True), verdict(m, h, True)))
        if runs.get('view'):
            m, h = mean_ci(_paired(runs['place'], runs['view'], lambda r: window(r, 'end')))
            rows.append(('Place ends above View (end, Place - View)', _fmt(m, h, pct=True),
                         verdict(m, h, True)))
        if inn:
            m, h = mean_ci(_paired(runs['place'], inn, lambda r: window(r, 'end')))
            rows.append(('Place ends above Innate (end, Place - Innate)', _fmt(m, h, pct=True),
                         verdict(m, h, True)))
    for c in ('sync', 'async'):
        rs = runs.get(c, [])
        if not rs or not singles:
            continue
        best = max(singles, key=lambda s: np.mean([window(r, 'end') for r in runs[s]]))
        m, h = mean_ci(_paired(rs, runs[best], lambda r: window(r, 'end')))
        rows.append((f'{c.capitalize()} ends best (end, {c} - best single = {best})',
                     _fmt(m, h, pct=True), verdict(m, h, True)))
        for other in singles:
            if other != best:
                m, h = mean_ci(_paired(rs, runs[other], lambda r: window(r, 'end')))
                rows.append((f'{c.capitalize()} ends above {other} (end, {c} - {other})',
                             _fmt(m, h, pct=True), verdict(m, h, True)))
        for mod in ('view', 'place'):
            if runs.get(mod) and all(mod in r.solo for r in rs):
                m, h = mean_ci(_paired(rs, runs[mod],
                                       lambda r, mod=mod: r.solo[mod]['reached']
                                       / r.solo[mod]['n'],
                                       lambda r: _rate(r)[1][-1]))
                rows.append((f'M_{mod[:2]} trained in {c}, alone, minus {mod} alone (last point)',
                             _fmt(m, h, pct=True), verdict(m, h, True)))
    for c in ('sync', 'async'):
        rs = runs.get(c, [])
        if not rs:
            continue
        n = len(rs[0].episodes)
        for name, lo, hi in (('mid', int(0.3 * n), int(0.6 * n)),
                             ('end', max(0, n - WINDOW), n)):
            sh = np.array([shares(r, lo, hi) for r in rs])
            cells = ', '.join(f'{m} {_fmt(*mean_ci(sh[:, k]), pct=True)}'
                              for k, m in enumerate(rs[0].modules))
            rows.append((f'Fig. 3{"b" if c == "sync" else "c"}: {c} shares, episodes '
                         f'{lo}-{hi} ({name})', cells, '-'))
    if runs.get('sync') and runs.get('async'):
        for s in sorted({e['start'] for e in runs['async'][0].evals}):
            m, h = mean_ci(_paired(runs['async'], runs['sync'],
                                   lambda r, s=s: eval_time(r, s)))
            a = _fmt(*mean_ci([eval_time(r, s) for r in runs['async']]), unit=' s')
            b = _fmt(*mean_ci([eval_time(r, s) for r in runs['sync']]), unit=' s')
            paper = 'faster' if s in ('A', 'B', 'C') else 'no difference'
            rows.append((f'Fig. 5 from {s}: Async vs Sync (paper: Async {paper})',
                         f'{a} vs {b}; Async - Sync {_fmt(m, h, unit=" s")}',
                         verdict(m, h, False) if s in ('A', 'B', 'C') else
                         no_difference(m, h)))
    return rows


def markdown(rows: list[tuple[str, str, str]], runs: dict[str, list[JobResult]]) -> str:
    n = ', '.join(f'{c} {len(rs)}' for c, rs in runs.items())
    spec = next(iter(runs.values()))[0].spec
    arena = Path(spec.get('arena') or 'config/arena.yaml').name
    out = [f"Preset `{spec.get('preset') or 'paper'}`, arena `{arena}`. Seeds: {n}. "
           'Mean ± 95% t-interval over seeds (none below 3 seeds).', '',
           '| claim (paper, Sec. IV) | measured | holds? |', '|---|---|---|']
    out += [f'| {a} | {b} | {c} |' for a, b, c in rows]
    return '\n'.join(out)


def main(args: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog='python -m clis_app.experiments.claims',
                                description=__doc__.split('\n\n')[0])
    p.add_argument('out', type=Path, help='a clis experiment folder (its runs/)')
    a = p.parse_args(args)
    try:
        runs = load_runs(a.out)
    except ValueError as exc:
        print(f'claims: {exc}', file=sys.stderr)
        return 2
    if not runs:
        print(f'claims: no run of {", ".join(PAPER)} without @ overrides in {a.out}/runs',
              file=sys.stderr)
        return 2
    print(markdown(claims(runs), runs))
    return 0


if __name__ == '__main__':
    sys.exit(main())
