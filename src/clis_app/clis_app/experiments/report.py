"""``clis report``: the measured numbers behind docs/results.md, from saved experiment folders.

For each condition: successes per block at a few points of learning (mean and 95% t-band over
seeds), the first block whose mean reaches Innate's level, the evaluation from A-E, who acted
(selection shares early, mid, late), the selection probability of eq. (3) at the start state,
and the importance products (median log10 c of off-policy episodes). Markdown on stdout.
"""

from __future__ import annotations

import argparse
from pathlib import Path
import sys

from clis_modules.core.plugin import TIMINGS, condition_order, solo_condition
import numpy as np

from clis_app.experiments.figures import MIN_BAND_SEEDS, STARTS, band
from clis_app.experiments.runner import JobResult


class ReportError(ValueError):
    """A folder that is not a finished experiment."""


def load_runs(folders: list[Path]) -> list[JobResult]:
    """The runs of each experiment folder: those its ``experiment.json`` lists (runs left in
    ``runs/`` by an earlier experiment with other conditions or seeds are not its results),
    or every run in ``runs/`` for a folder without one."""
    import json

    from clis_app.experiments.runner import result_path
    runs = []
    for folder in folders:
        if not folder.is_dir():
            raise ReportError(f'{folder}: no such folder')
        paths = sorted((folder / 'runs').glob('*.json'))
        exp_path = folder / 'experiment.json'
        if exp_path.is_file():
            exp = json.loads(exp_path.read_text())
            listed = [result_path(folder / 'runs', lb, seed)
                      for lb in exp.get('labels') or list(exp.get('overrides', {}))
                      for seed in exp.get('seeds', [])]
            paths = [p for p in listed if p.is_file()] if listed else paths
        if not paths:
            raise ReportError(f'no runs in {folder}/runs (run clis experiment)')
        for path in paths:
            try:
                runs.append(JobResult.load(path))
            except (ValueError, TypeError, OSError) as exc:
                raise ReportError(f'{path}: not a readable run ({exc})') from None
    # the paper's order (innate, view, place, sync, async), each followed by its variants
    return sorted(runs, key=lambda r: (condition_order(r.spec['condition']),
                                       r.spec['label'] != r.spec['condition'],
                                       r.spec['label'], r.spec['seed']))


def _finite_stat(values: np.ndarray, fn=np.mean) -> float:
    """``fn`` of the finite values, NaN when there are none (no warning)."""
    values = np.asarray(values, float)
    values = values[np.isfinite(values)]
    return float(fn(values)) if values.size else float('nan')


def _fmt(mean: float, half: float) -> str:
    """``mean ± half``; the mean alone where there is no band (fewer than 3 seeds)."""
    return f'{mean:.1f} ± {half:.1f}' if np.isfinite(half) else f'{mean:.1f}'


def _band_note(runs: list[JobResult]) -> str:
    """The note under a table when a condition has too few seeds for its ± column."""
    labels = list(dict.fromkeys(r.spec['label'] for r in runs))
    few = [lb for lb in labels
           if sum(r.spec['label'] == lb for r in runs) < MIN_BAND_SEEDS]
    if not few:
        return ''
    return (f'\nNo ± for {", ".join(few)}: fewer than {MIN_BAND_SEEDS} seeds, a 95% t-band '
            'would be wider than the scale (mean only).')


def report(runs: list[JobResult]) -> str:
    labels = list(dict.fromkeys(r.spec['label'] for r in runs))
    by = {lb: [r for r in runs if r.spec['label'] == lb] for lb in labels}
    block = runs[0].block
    innate = by.get('innate') or next((rs for rs in by.values()
                                       if rs[0].spec['condition'] == 'innate'), None)
    innate_level = (float(np.mean([r.success_curve() for r in innate])) if innate else None)
    n_blocks = min(len(r.success_curve()) for r in runs)
    points = sorted({0, 2, 5, n_blocks // 2, n_blocks - 1} & set(range(n_blocks)))
    head = ' | '.join(f'ep {(k + 1) * block}' for k in points)
    out = [f'Successes per {block} learning episodes (mean ± 95% t-band over seeds); '
           + (f"Innate's level = {innate_level:.1f}." if innate_level is not None else ''), '',
           f'| condition | seeds | {head} | first block at Innate level | eval success A-E |',
           '|---|---|' + '---|' * len(points) + '---|---|']
    for lb, rs in by.items():
        curves = np.array([r.success_curve()[:n_blocks] for r in rs], float)
        mean, half = band(curves)
        cells = ' | '.join(_fmt(mean[k], half[k]) for k in points)
        reach = 'n/a'
        if innate_level is not None and rs[0].spec['condition'] != 'innate':
            hit = np.nonzero(mean >= innate_level)[0]
            reach = f'ep {(hit[0] + 1) * block}' if hit.size else 'never'
        ev = np.mean([[e['reached'] for e in r.evals] for r in rs])
        out.append(f'| {lb} | {len(rs)} | {cells} | {reach} | {100 * ev:.0f}% |')
    out += ['', 'Evaluation after learning: mean time to the destination [s] from each start '
            '(timeouts count as 60 s; mean ± 95% t-band over seeds) and success rate.', '',
            '| condition | ' + ' | '.join(STARTS) + ' |', '|---|' + '---|' * len(STARTS)]
    for lb, rs in by.items():
        per_seed = np.array([[np.mean([e['duration'] for e in r.evals if e['start'] == s])
                              for s in STARTS] for r in rs])
        succ = np.array([[np.mean([e['reached'] for e in r.evals if e['start'] == s])
                          for s in STARTS] for r in rs]).mean(0)
        mean, half = band(per_seed)
        out.append(f'| {lb} | ' + ' | '.join(
            f'{m:.1f} ± {h:.1f} ({100 * sc:.0f}%)' for m, h, sc in zip(mean, half, succ))
            + ' |')
    multi = [lb for lb in labels if len(by[lb][0].modules) > 1]
    if multi:
        thirds = [(0, n_blocks // 3), (n_blocks // 3, 2 * n_blocks // 3),
                  (2 * n_blocks // 3, n_blocks)]
        out += ['', 'Who acted (share of episode time; first, middle and last third of '
                'learning), Pr(i | x(0)) of eq. (3) over the run (min-max of block means), and '
                'the median log10 of the importance product c at the end of episodes in which '
                'the module did not act (last third), and the largest |V_i(x(0))| of the run '
                '(median over seeds; a return is at most 1 and rarely below -1, so more means '
                'TD diverged).', '',
                '| condition | module | share early | share mid | share late | Pr(i\\|x0) | '
                'median log10 c | max abs V |', '|---|---|---|---|---|---|---|---|']
        for lb in multi:
            rs = by[lb]
            for k, name in enumerate(rs[0].modules):
                shares = np.mean([r.selection_shares()[:n_blocks, k] for r in rs], axis=0)
                sh = [100 * _finite_stat(shares[a:b]) for a, b in thirds]
                p = np.mean([r.block_stat(f'p_{name}')[:n_blocks] for r in rs], axis=0)
                logc = _finite_stat(np.concatenate(
                    [r.block_stat(f'log10c_{name}', np.median)[thirds[2][0]:n_blocks]
                     for r in rs]), np.median)
                vmax = np.median([np.nanmax(np.abs([e[f'v_{name}'] for e in r.episodes]))
                                  for r in rs])
                out.append(f'| {lb} | {name} | {sh[0]:.0f}% | {sh[1]:.0f}% | {sh[2]:.0f}% | '
                           f'{p.min():.2f}-{p.max():.2f} | {logc:.1f} | {vmax:.3g} |')
    return '\n'.join(out)


def _ci(values) -> str:
    values = np.asarray(values, float)[:, None]
    mean, half = band(values)
    return _fmt(mean[0], half[0])


def innate_eval_level(runs: list[JobResult]) -> float | None:
    """Innate's level on the evaluation curve: its mean successes over seeds and points (its
    policy is fixed, so every point estimates the same number)."""
    curves = [r.eval_success_curve() for r in runs
              if r.spec['condition'] == 'innate' and r.eval_curve]
    return float(np.mean([np.mean(c) for c in curves])) if curves else None


def episodes_to_level(runs: list[JobResult], level: float) -> int | None:
    """First evaluation point whose mean over seeds reaches ``level`` (None: never)."""
    n = min(len(r.eval_curve) for r in runs)
    mean = np.mean([r.eval_success_curve()[:n] for r in runs], axis=0)
    hit = np.nonzero(mean >= level)[0]
    return runs[0].eval_points()[hit[0]] if hit.size else None


def eval_report(runs: list[JobResult]) -> str:
    """Tables of the evaluation curve (Fig. 3a, paper protocol), the thesis test (each learned
    module of a multi-module run evaluated alone) and the importance weights."""
    runs = [r for r in runs if r.eval_curve]
    if not runs:
        return ''
    labels = list(dict.fromkeys(r.spec['label'] for r in runs))
    by = {lb: [r for r in runs if r.spec['label'] == lb] for lb in labels}
    level = innate_eval_level(runs)
    n_eval = int(runs[0].eval_curve[0]['n'])
    every = sorted({p for r in runs for p in r.eval_points()})
    show = [p for p in (0, 50, 100, 150, 300, 500) if p in every] + [every[-1]]
    show = list(dict.fromkeys(show))
    out = [f'Evaluation curve (Fig. 3a): successes in {n_eval} episodes from A-E with learning '
           'off, after the given number of learning episodes (mean ± 95% t-band over seeds)'
           + (f"; Innate's level = {level:.1f}." if level is not None else '.'), '',
           '| condition | seeds | ' + ' | '.join(f'ep {p}' for p in show)
           + " | episodes to Innate's level | final eval success |",
           '|---|---|' + '---|' * len(show) + '---|---|']
    for lb, rs in by.items():
        n = min(len(r.eval_curve) for r in rs)
        curves = np.array([r.eval_success_curve()[:n] for r in rs], float)
        pts = rs[0].eval_points()[:n]
        mean, half = band(curves)
        cells = ' | '.join(_fmt(mean[pts.index(p)], half[pts.index(p)]) if p in pts
                           else '-' for p in show)
        reach = 'n/a'
        if level is not None and rs[0].spec['condition'] != 'innate':
            hit = episodes_to_level(rs, level)
            reach = 'never' if hit is None else str(hit)
        episodes = int(rs[0].spec.get('episodes', pts[-1]))
        if pts[-1] >= episodes:                    # the curve's last point is after learning
            final = 100.0 * curves[:, -1] / n_eval
        else:   # fewer episodes than --eval-every: the evaluation after learning (A-E)
            final = [100.0 * np.mean([e['reached'] for e in r.evals]) if r.evals
                     else np.nan for r in rs]
        out.append(f'| {lb} | {len(rs)} | {cells} | {reach} | {_ci(final)}% (ep {episodes}) |')
    multi = [lb for lb in labels if by[lb][0].solo]
    def single(multi_label: str, name: str) -> str | None:
        """The single-module label of the same preset (``improved:place`` for
        ``improved:async``), else the paper preset's."""
        head = multi_label.split('@')[0]
        first = head.split(':')[0]
        prefix = first + ':' if ':' in head and first not in TIMINGS else ''
        for cand in (prefix + name, name, prefix + solo_condition(name), solo_condition(name)):
            if cand in by and len(by[cand][0].modules) == 1:
                return cand
        return None
    if multi:
        out += ['', 'The thesis measured directly: each learned module, trained inside the '
                'multi-module condition, then evaluated acting alone from A-E (learning off, '
                f"{n_eval} episodes, the same evaluation draws as the single-module runs' "
                'last point); success % (mean ± 95% t-band over seeds).', '',
                '| trained in | module | alone-evaluated success | trained alone (same episodes)'
                ' |', '|---|---|---|---|']
        for lb in multi:
            for name in by[lb][0].solo:
                inside = [100.0 * r.solo[name]['reached'] / r.solo[name]['n'] for r in by[lb]]
                alone, ref = 'n/a', single(lb, name)
                if ref is not None:
                    alone = _ci([100.0 * r.eval_success_curve()[-1] / n_eval
                                 for r in by[ref]]) + f'% ({ref})'
                out.append(f'| {lb} | {name} | {_ci(inside)}% | {alone} |')
        out += ['', 'Importance weights of the learned modules over the last third of learning '
                '(median over episodes of the per-episode median weight c_median -- the product'
                " c_l of (8) under the paper's rules, the per-step min(rho_bar, rho_l) under "
                'retrace -- and of the effective sample size (sum c)^2 / sum c^2 in steps; '
                'mean over seeds).', '']
        # the learned modules (those evaluated alone), in the order of the conditions
        learned = list(dict.fromkeys(name for lb in multi for name in by[lb][0].solo))
        out += ['| condition | ' + ' | '.join(f'{name}: median weight | {name}: ESS'
                                             for name in learned) + ' |',
                '|---|' + '---|---|' * len(learned)]
        for lb in multi:
            cells = []
            for name in learned:
                med, ess = [], []
                for r in by[lb]:
                    last = r.episodes[2 * len(r.episodes) // 3:]
                    med.append(_finite_stat([e.get(f'c_median_{name}', np.nan) for e in last],
                                            np.median))
                    ess.append(_finite_stat([e.get(f'ess_{name}', np.nan) for e in last],
                                            np.median))
                cells += [f'{_finite_stat(med):.3g}', f'{_finite_stat(ess):.1f}']
            out.append(f'| {lb} | ' + ' | '.join(cells) + ' |')
    return '\n'.join(out)


def register(sub: argparse._SubParsersAction) -> None:
    from clis_app.cli.help import HelpFormatter
    p = sub.add_parser('report', help='tables of measured results from experiment folders',
                       description=__doc__, formatter_class=HelpFormatter)
    p.add_argument('folders', type=Path, nargs='+', help='output folders of clis experiment')
    p.set_defaults(func=_main)


def _main(args: argparse.Namespace) -> int:
    try:
        runs = load_runs(args.folders)
    except (ReportError, ValueError, OSError) as exc:
        print(f'clis report: {" ".join(str(exc).split())}', file=sys.stderr)
        return 2
    ev = eval_report(runs)
    print((ev + '\n\n' if ev else '') + report(runs) + _band_note(runs))
    return 0
