"""The report of ``clis study``, from the run summaries in ``DIR/runs`` (and the layouts in
``DIR/arenas``) alone: ``report.md``, ``report.json``, ``forest.png``, ``hidden_share.png``,
``layouts.png`` (docs/study.md).

Per preset, protocol and layout: each condition's final evaluated success (the last
evaluation point, A-E, learning off) with its 95% t-interval over seeds clipped to [0, 100]
and the share of its runs that end below Innate's mean; Async minus each single module;
Async minus the best single module, chosen on the same seeds (in-sample) and chosen on the
other seeds (leave one seed out); whether Async is above every single module; the thesis test
(M_vi and M_pl trained inside Async, evaluated alone, minus the same module trained alone).
Each difference is paired over seeds with its 95% t-interval, and the per-layout values are
aggregated over layouts.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from functools import partial
import json
import math
from pathlib import Path
import sys
from typing import Any

import numpy as np

from clis_app import files
from clis_app.cli.errors import fail
from clis_app.study.markdown import _markdown, _order

__all__ = ['SUMMARY_FORMAT', 'PROTOCOLS', 'ReportError', 'load_summaries', 'study_summaries',
           'is_single', 'rate_interval', 'leave_one_out_best', 'below_level', 'report',
           'report_only']

#: Format of the per-run summary files.
SUMMARY_FORMAT = 1
#: Start protocols of a study (``--train-start`` of ``clis experiment``), in report order.
PROTOCOLS = ('wander', 'starts', 'random')


class ReportError(ValueError):
    """A study folder whose summaries cannot be read."""


def _atomic_json(path: Path, data: Any) -> None:
    """``data`` as the study's JSON files are written (sorted keys, a final newline)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    files.write_text(path, json.dumps(data, indent=1, sort_keys=True) + '\n')


#: ``clis study: MESSAGE`` on one line, exit code 2 (:func:`clis_app.cli.errors.fail`)
_fail = partial(fail, 'study')


def load_summaries(out: Path) -> list[dict]:
    """Every run summary in ``DIR/runs`` (sorted by arena, protocol, preset, condition,
    seed)."""
    rows = []
    for path in sorted((out / 'runs').rglob('*.json')):
        try:
            data = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            raise ReportError(f'{path}: not a readable run summary ({exc})') from None
        if data.get('format') != SUMMARY_FORMAT:
            raise ReportError(f'{path}: not a run summary of format {SUMMARY_FORMAT}')
        rows.append(data)
    rows.sort(key=lambda d: (d['arena'], d['protocol'], d['preset'], d['condition'],
                             d['seed']))
    return rows


def _planned(out: Path) -> tuple[list[dict], int | None, str | None, int]:
    """:func:`study_summaries`, and how many summaries in ``DIR/runs`` are of runs outside
    the plan."""
    summaries = load_summaries(out)
    if not (out / 'plan.json').is_file():
        return summaries, None, None, 0
    plan_data = json.loads((out / 'plan.json').read_text())
    keys = {tuple(k) for k in plan_data['runs']}
    # runs of an earlier, larger SPEC left in DIR/runs are not this study's
    kept = [d for d in summaries
            if (d['arena'], d['protocol'], d['preset'], d['condition'], d['seed']) in keys]
    return kept, len(keys), plan_data.get('name'), len(summaries) - len(kept)


def study_summaries(out: Path) -> tuple[list[dict], int | None, str | None]:
    """The summaries of the study in ``out`` (those of its ``plan.json``, when it has one),
    the number of runs planned and the study's name."""
    return _planned(out)[:3]


def report_only(out: Path) -> int:
    """Write ``DIR/report.md``, ``report.json`` and the figures from the summaries."""
    try:
        summaries, planned, name, outside = _planned(out)
    except (ValueError, KeyError, TypeError) as exc:
        return _fail(f'--out {out}: {exc}')
    if not summaries:
        return _fail(f'--out {out}: no run summaries in {out}/runs (not a study folder, or '
                     'no run finished yet)')
    rep = report(summaries, planned, name, outside)
    files.write_text(out / 'report.md', rep['markdown'])
    _atomic_json(out / 'report.json', rep['numbers'])
    drawn = _draw(rep['numbers'], out)
    md = rep['markdown']
    print(md[:md.find('\n## Preset')] if '\n## Preset' in md else md)
    print(f'wrote {out}/' + ', '.join(['report.md', 'report.json'] + drawn), file=sys.stderr)
    return 0


def _rate(d: Mapping[str, Any]) -> float:
    return d['final']['reached'] / d['final']['n']


def _solo_rate(d: Mapping[str, Any], module: str) -> float:
    s = d['solo'].get(module)
    return s['reached'] / s['n'] if s else math.nan


def _ci(values: list[float]) -> tuple[float, float, int]:
    from clis_app.experiments.claims import mean_ci
    m, h = mean_ci(values)
    return m, h, int(np.isfinite(np.asarray(values, float)).sum()) if values else 0


def rate_interval(values: Sequence[float]) -> dict[str, float]:
    """The mean of success rates in % and its 95% t-interval, clipped to [0, 100].

    Parameters
    ----------
    values : sequence of float
        Success rates in %, one per run (seed or layout); NaN values are left out.

    Returns
    -------
    dict
        ``mean``, ``half`` (the t-interval's half-width, NaN below 3 values), ``low`` and
        ``high`` (``mean -+ half`` clipped to [0, 100]; NaN without an interval) and ``n``
        (the finite values).
    """
    m, h, n = _ci(list(values))
    if not math.isfinite(h):
        return {'mean': m, 'half': h, 'low': math.nan, 'high': math.nan, 'n': n}
    return {'mean': m, 'half': h, 'low': max(0.0, m - h), 'high': min(100.0, m + h), 'n': n}


def below_level(values: Sequence[float], level: float) -> tuple[int, int]:
    """How many of ``values`` (finite) lie below ``level``, and of how many.

    Parameters
    ----------
    values : sequence of float
        One value per run (final success rates in %).
    level : float
        The level (Innate's mean on the same layout, in the report).

    Returns
    -------
    tuple of int
        ``(below, n)``; a value within 1e-9 of ``level`` is not below it.
    """
    vals = [v for v in values if math.isfinite(v)]
    return sum(v < level - 1e-9 for v in vals), len(vals)


def leave_one_out_best(target: Mapping[int, float],
                       singles: Mapping[str, Mapping[int, float]]
                       ) -> dict[int, tuple[str, float]]:
    """``target`` minus the best single module chosen without the seed it is judged on.

    For each seed ``s`` of ``target``, the single module with the highest mean over the
    seeds other than ``s`` (a tie goes to the module listed first in ``singles``) is the
    comparator, and the difference is ``target[s]`` minus that module's value at ``s``. A
    module without a run at ``s`` or without another seed is not a candidate for ``s``.

    Parameters
    ----------
    target : mapping of int to float
        Async's value per seed.
    singles : mapping of str to mapping of int to float
        Each single module's value per seed, in the order that breaks ties.

    Returns
    -------
    dict
        ``{seed: (module chosen, target[seed] - module[seed])}`` for the seeds that have a
        candidate.
    """
    out = {}
    order = list(singles)
    for s in sorted(target):
        if not math.isfinite(target[s]):
            continue
        means = {}
        for c in order:
            rest = [v for t, v in singles[c].items() if t != s and math.isfinite(v)]
            if s in singles[c] and math.isfinite(singles[c][s]) and rest:
                means[c] = float(np.mean(rest))
        if means:
            best = max(means, key=lambda c: (means[c], -order.index(c)))
            out[s] = (best, target[s] - singles[best][s])
    return out


def _verdict(m: float, h: float) -> str:
    """'above' / 'below' when the 95% interval excludes 0, '' otherwise (or no interval)."""
    if not (math.isfinite(m) and math.isfinite(h)):
        return ''
    return 'above' if m - h > 0 else ('below' if m + h < 0 else '')


def _paired(a: Mapping[int, float], b: Mapping[int, float]) -> list[float]:
    return [a[s] - b[s] for s in sorted(a) if s in b and math.isfinite(a[s] - b[s])]


def _diff(values: list[float]) -> dict[str, Any]:
    m, h, n = _ci(values)
    return {'mean': m, 'half': h, 'n': n, 'verdict': _verdict(m, h)}


def is_single(condition: str) -> bool:
    """Whether ``condition`` has one module (View, Place... alone)."""
    from clis_modules.core.plugin import parse_condition
    return len(parse_condition(condition).modules) == 1


def _cell(summaries: list[dict], base: list[dict] | None = None) -> dict:
    """The numbers of one layout, protocol and preset (in points, i.e. percent); ``base``:
    the runs of the preset it borrows its single modules from (``singles``), whose Async it
    is compared with."""
    by: dict[str, dict[int, dict]] = {}
    for d in summaries:
        by.setdefault(d['condition'], {})[d['seed']] = d
    rates = {c: {s: 100 * _rate(d) for s, d in runs.items()} for c, runs in by.items()}
    cell: dict[str, Any] = {'conditions': {}, 'seeds': sorted({d['seed'] for d in summaries}),
                            'hidden_share': summaries[0]['hidden_share'],
                            'layout_seed': summaries[0]['settings'].get('layout_seed')}
    for c in _order(rates):
        cell['conditions'][c] = rate_interval(list(rates[c].values()))
    if 'innate' in rates:
        level = cell['conditions']['innate']['mean']
        for c in cell['conditions']:
            if c != 'innate':
                cell['conditions'][c]['below_innate'] = list(below_level(
                    list(rates[c].values()), level))
    singles = [c for c in _order(rates) if is_single(c)]
    if 'async' in rates and singles:
        each = {c: _diff(_paired(rates['async'], rates[c])) for c in singles}
        cell['async_minus'] = each
        # above every single module: the rule of the verdict, judged on each interval
        cell['async_all'] = {'verdict': 'above' if all(v['verdict'] == 'above'
                                                       for v in each.values()) else ''}
        # the best single chosen on the seeds it is compared on (in-sample)
        best = max(singles, key=lambda c: (cell['conditions'][c]['mean'], -singles.index(c)))
        cell['async_best'] = {'best': best, **each[best]}
        # the best single chosen on the other seeds (leave one seed out)
        loo = leave_one_out_best(rates['async'], {c: rates[c] for c in singles})
        if loo:
            cell['async_best_loo'] = {'chosen': {str(s): c for s, (c, _) in loo.items()},
                                      **_diff([v for _, v in loo.values()])}
    for module in ('view', 'place'):
        if 'async' in rates and module in rates:
            solo = {s: 100 * _solo_rate(d, module) for s, d in by['async'].items()}
            cell[f'thesis_{module}'] = _diff(_paired(solo, rates[module]))
    if 'innate' in rates and 'view' in rates:
        m, h, n = _ci(_paired(rates['view'], rates['innate']))
        cell['view_innate'] = {'mean': m, 'half': h, 'n': n}
    base_async = {d['seed']: 100 * _rate(d) for d in base or [] if d['condition'] == 'async'}
    if 'async' in rates and base_async:
        cell['async_vs_base'] = _diff(_paired(rates['async'], base_async))
    return cell


#: The differences aggregated over layouts, each a key of a layout's numbers.
_AGGREGATED = ('async_best', 'async_best_loo', 'thesis_view', 'thesis_place', 'view_innate',
               'async_vs_base')


def _aggregate(values: list[dict]) -> dict[str, Any]:
    """The mean of per-layout differences, its t-interval over layouts and verdict, and the
    counts of layouts whose own interval is above, below or neither."""
    m, h, n = _ci([v['mean'] for v in values])
    verdicts = [v.get('verdict', '') for v in values]
    return {'mean': m, 'half': h, 'layouts': n, 'verdict': _verdict(m, h),
            'above': verdicts.count('above'), 'below': verdicts.count('below'),
            'unresolved': verdicts.count('')}


def report(summaries: list[dict], planned: int | None = None, name: str | None = None,
           outside: int = 0) -> dict:
    """The study's report from its run summaries.

    Per preset, protocol and layout: each condition's final evaluated success (the last
    evaluation point, A-E, learning off) over seeds, with its 95% t-interval clipped to
    [0, 100] and how many runs end below Innate's mean; Async minus each single module, minus
    the best single chosen on the same seeds (in-sample) and minus the best single chosen on
    the other seeds (:func:`leave_one_out_best`), and whether Async is above every single
    module; the thesis test, M_vi and M_pl trained inside Async and evaluated alone minus the
    same module trained alone (the same evaluation draws). Each difference is paired over
    seeds with its 95% t-interval; per preset and protocol the per-layout values are
    aggregated over layouts (a t-interval over layouts), with the counts of layouts above
    and below.

    Parameters
    ----------
    summaries : list of dict
        The run summaries (``DIR/runs``) of the study's plan.
    planned : int, optional
        How many runs the plan has.
    name : str, optional
        The study's name (the report's title).
    outside : int
        How many summaries in ``DIR/runs`` are of runs outside the plan (not reported).

    Returns
    -------
    dict
        ``{'markdown': text, 'numbers': dict}``, the numbers with NaN as None.
    """
    groups: dict[tuple[str, str], dict[str, list[dict]]] = {}
    for d in summaries:
        groups.setdefault((d['preset'], d['protocol']), {}).setdefault(d['arena'], []).append(d)
    # a preset with `singles: OTHER` is compared with OTHER's single-module runs
    borrowed = {key: next((d['settings']['singles'] for rows in arenas.values() for d in rows
                           if d['settings'].get('singles')), None)
                for key, arenas in groups.items()}
    for (preset, proto), other in borrowed.items():
        if other is None:
            continue
        for arena, rows in groups[(preset, proto)].items():
            seeds = {d['seed'] for d in rows}
            rows += [d for d in groups.get((other, proto), {}).get(arena, [])
                     if is_single(d['condition']) and d['seed'] in seeds]
    numbers: dict[str, Any] = {'name': name, 'runs': len(summaries), 'planned': planned,
                               'outside_plan': outside, 'groups': []}
    for (preset, proto) in sorted(groups, key=lambda k: (k[0], PROTOCOLS.index(k[1])
                                                         if k[1] in PROTOCOLS else 9, k[1])):
        other = borrowed[(preset, proto)]
        cells = {a: _cell(rows, None if other is None
                          else groups.get((other, proto), {}).get(a, []))
                 for a, rows in sorted(groups[(preset, proto)].items())}
        if other is not None:
            for c in cells.values():          # the other preset's, not this one's
                c.pop('view_innate', None)
        # over the generated layouts where the group has any (nobody designed or tuned on
        # them), else over all its layouts
        generated = {a: c for a, c in cells.items() if c['layout_seed'] is not None}
        pool = generated or cells
        agg: dict[str, Any] = {'over': 'generated' if generated else 'all',
                               'n_layouts': len(pool)}
        for key in _AGGREGATED:
            per = [c[key] for c in pool.values() if key in c]
            if per:
                agg[key] = _aggregate(per)
        conds = _order(dict.fromkeys(c for cell in cells.values() for c in cell['conditions']))
        singles = [c for c in conds if is_single(c)]
        for c in singles:
            per = [cell['async_minus'][c] for cell in pool.values()
                   if c in cell.get('async_minus', {})]
            if per:
                agg.setdefault('async_minus', {})[c] = _aggregate(per)
        if agg.get('async_minus'):
            alls = [cell['async_all']['verdict'] for cell in pool.values() if 'async_all' in cell]
            agg['async_all'] = {
                'above': alls.count('above'), 'layouts': len(alls),
                'interval': all(math.isfinite(a['half']) for a in agg['async_minus'].values()),
                'verdict': 'above' if all(a['verdict'] == 'above'
                                          for a in agg['async_minus'].values()) else ''}
        for c in conds:
            ok = [cell for cell in pool.values() if c in cell['conditions']]
            agg.setdefault('conditions', {})[c] = rate_interval(
                [cell['conditions'][c]['mean'] for cell in ok])
            counts = [cell['conditions'][c]['below_innate'] for cell in ok
                      if 'below_innate' in cell['conditions'][c]]
            if counts:
                agg['conditions'][c]['below_innate'] = [sum(n for n, _ in counts),
                                                        sum(k for _, k in counts)]
        numbers['groups'].append({'preset': preset, 'protocol': proto, 'conditions': conds,
                                  'layouts': cells, 'aggregate': agg,
                                  'singles_from': borrowed[(preset, proto)],
                                  'diverged': divergence_counts(
                                      [d for rows in groups[(preset, proto)].values()
                                       for d in rows if d['preset'] == preset])})
    return {'markdown': _markdown(numbers), 'numbers': _finite(numbers)}


def divergence_counts(summaries: list[dict]) -> dict:
    """Of ``summaries``: how many record the divergence guard's result (``recorded``; a run
    summarised before the guard existed does not), and per condition how many of those had a
    module diverge (``{condition: [diverged, recorded]}``)."""
    recorded = [d for d in summaries if 'diverged' in d]
    by: dict[str, list[int]] = {}
    for d in recorded:
        n = by.setdefault(d['condition'], [0, 0])
        n[0] += bool(d['diverged'])
        n[1] += 1
    return {'runs': len(summaries), 'recorded': len(recorded),
            'diverged': sum(bool(d['diverged']) for d in recorded), 'conditions': by}


def _finite(obj: Any) -> Any:
    """NaN as None (JSON)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_finite(v) for v in obj]
    return obj


def _draw(numbers: dict, out: Path) -> list[str]:
    """Draw the figures the numbers allow; remove those they do not (a figure of an earlier
    report is not this one's). Returns the names of the figures drawn."""
    from clis_app.study.figures import ForestRow, forest_plot, hidden_scatter
    drawn = []
    panels: dict[str, dict[str, list]] = {}
    for g in numbers['groups']:
        rows = panels.setdefault(g['protocol'], {}).setdefault(g['preset'], [])
        a = g['aggregate']
        items = [(name, c, False) for name, c in g['layouts'].items()]
        if a.get('async_all') and a['async_all']['layouts'] >= 3:   # an aggregate, not a copy
            items.append(('over generated layouts' if a['over'] == 'generated'
                          else 'over layouts', a, True))
        for label, c, is_agg in items:
            above = (c.get('async_all') or {}).get('verdict') == 'above'
            series = [(f'Async - {m}', d) for m, d in c.get('async_minus', {}).items()]
            series.append(('Async - best single, leave one out', c.get('async_best_loo')))
            for what, d in series:
                if d and d.get('mean') is not None:
                    rows.append(ForestRow(label, what, d['mean'], _nan(d.get('half')),
                                          aggregate=is_agg, above=above))
    panels = {p: {k: v for k, v in by.items() if v} for p, by in panels.items()}
    panels = {p: by for p, by in panels.items() if by}
    if panels:
        forest_plot(panels, out / 'forest.png',
                    'Async minus each single module, and minus the best single chosen on the '
                    'other seeds: final evaluated success, paired over seeds, mean ± 95% CI.\n'
                    'Shaded: Async above every single module (each of its intervals against '
                    'a single module above 0)', 'Async - comparator [points]')
        drawn.append('forest.png')
    points = []
    for g in numbers['groups']:
        for name, c in g['layouts'].items():
            vi = c.get('view_innate')
            if vi and vi['mean'] is not None:
                points.append((g['protocol'], g['preset'], name, c['hidden_share'],
                               vi['mean'], _nan(vi['half']), c['layout_seed'] is not None))
    if points:
        hidden_scatter(points, out / 'hidden_share.png',
                       'View - Innate against how much of the floor hides the goal')
        drawn.append('hidden_share.png')
    arenas = _study_arenas(numbers, out)
    if arenas:
        from cr_sim.core.robot import load_robot_params

        from clis_app.study.figures import layout_gallery
        layout_gallery(arenas, load_robot_params().radius, out / 'layouts.png')
        drawn.append('layouts.png')
    for name in ('forest.png', 'hidden_share.png', 'layouts.png'):
        if name not in drawn:
            (out / name).unlink(missing_ok=True)
    return drawn


def _study_arenas(numbers: dict, out: Path) -> list[tuple[str, Any]]:
    """The arenas of the report's layouts, read from ``DIR/arenas`` (none if one is
    missing: the gallery is drawn for the whole study or not at all)."""
    from cr_sim.core.arena import ArenaError, load_arena
    names = sorted({name for g in numbers['groups'] for name in g['layouts']})
    paths = [out / 'arenas' / f'{name}.yaml' for name in names]
    if not all(p.is_file() for p in paths):
        return []
    try:
        return [(name, load_arena(p)) for name, p in zip(names, paths)]
    except ArenaError:
        return []


def _nan(v: float | None) -> float:
    return math.nan if v is None else v

