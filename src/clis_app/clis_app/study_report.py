"""The report of ``clis study``, from the run summaries in ``DIR/runs`` (and the layouts in
``DIR/arenas``) alone: ``report.md``, ``report.json``, ``forest.png``, ``hidden_share.png``,
``layouts.png`` (docs/study.md).

Per preset, protocol and layout: each condition's final evaluated success (the last
evaluation point, A-E, learning off); Async - best single module; the thesis test (M_vi and
M_pl trained inside Async, evaluated alone, minus the same module trained alone), each paired
over seeds with its 95% t-interval; and the per-layout values aggregated over layouts.
"""

from __future__ import annotations

from collections.abc import Mapping
import json
import math
import os
from pathlib import Path
import sys
from typing import Any

import numpy as np

__all__ = ['SUMMARY_FORMAT', 'PROTOCOLS', 'ReportError', 'load_summaries', 'study_summaries',
           'is_single', 'report',
           'report_only']

#: Format of the per-run summary files.
SUMMARY_FORMAT = 1
#: Start protocols of a study (``--train-start`` of ``clis experiment``), in report order.
PROTOCOLS = ('wander', 'starts', 'random')


class ReportError(ValueError):
    """A study folder whose summaries cannot be read."""


def _atomic_text(path: Path, text: str) -> None:
    tmp = path.with_name(f'.{path.name}.tmp')
    tmp.write_text(text)
    os.replace(tmp, path)


def _atomic_json(path: Path, data: Any) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    _atomic_text(path, json.dumps(data, indent=1, sort_keys=True) + '\n')


def _fail(message: str, code: int = 2) -> int:
    print(f'clis study: {" ".join(str(message).split())}', file=sys.stderr)
    return code



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


def study_summaries(out: Path) -> tuple[list[dict], int | None, str | None]:
    """The summaries of the study in ``out`` (those of its ``plan.json``, when it has one),
    the number of runs planned and the study's name."""
    summaries = load_summaries(out)
    if not (out / 'plan.json').is_file():
        return summaries, None, None
    plan_data = json.loads((out / 'plan.json').read_text())
    keys = {tuple(k) for k in plan_data['runs']}
    # runs of an earlier, larger SPEC left in DIR/runs are not this study's
    return ([d for d in summaries if (d['arena'], d['protocol'], d['preset'], d['condition'],
                                      d['seed']) in keys], len(keys), plan_data.get('name'))


def report_only(out: Path) -> int:
    """Write ``DIR/report.md``, ``report.json`` and the figures from the summaries."""
    try:
        summaries, planned, name = study_summaries(out)
    except (ValueError, KeyError, TypeError) as exc:
        return _fail(f'--out {out}: {exc}')
    if not summaries:
        return _fail(f'--out {out}: no run summaries in {out}/runs (not a study folder, or '
                     'no run finished yet)')
    rep = report(summaries, planned, name)
    _atomic_text(out / 'report.md', rep['markdown'])
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
    from clis_app.claims import mean_ci
    m, h = mean_ci(values)
    return m, h, int(np.isfinite(np.asarray(values, float)).sum()) if values else 0


def _verdict(m: float, h: float) -> str:
    """'above' / 'below' when the 95% interval excludes 0, '' otherwise (or no interval)."""
    if not (math.isfinite(m) and math.isfinite(h)):
        return ''
    return 'above' if m - h > 0 else ('below' if m + h < 0 else '')


def _paired(a: dict[int, float], b: dict[int, float]) -> list[float]:
    return [a[s] - b[s] for s in sorted(a) if s in b and math.isfinite(a[s] - b[s])]


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
    for c, r in rates.items():
        m, h, n = _ci(list(r.values()))
        cell['conditions'][c] = {'mean': m, 'half': h, 'n': n}
    singles = [c for c in rates if is_single(c)]
    if 'async' in rates and singles:
        best = max(singles, key=lambda c: (cell['conditions'][c]['mean'], -singles.index(c)))
        m, h, n = _ci(_paired(rates['async'], rates[best]))
        each = {c: _verdict(*_ci(_paired(rates['async'], rates[c]))[:2]) for c in singles}
        verdict = ('above' if all(v == 'above' for v in each.values())
                   else 'below' if _verdict(m, h) == 'below' else '')
        cell['async_best'] = {'best': best, 'mean': m, 'half': h, 'n': n, 'verdict': verdict}
    for module in ('view', 'place'):
        if 'async' in rates and module in rates:
            solo = {s: 100 * _solo_rate(d, module) for s, d in by['async'].items()}
            m, h, n = _ci(_paired(solo, rates[module]))
            cell[f'thesis_{module}'] = {'mean': m, 'half': h, 'n': n, 'verdict': _verdict(m, h)}
    if 'innate' in rates and 'view' in rates:
        m, h, n = _ci(_paired(rates['view'], rates['innate']))
        cell['view_innate'] = {'mean': m, 'half': h, 'n': n}
    base_async = {d['seed']: 100 * _rate(d) for d in base or [] if d['condition'] == 'async'}
    if 'async' in rates and base_async:
        m, h, n = _ci(_paired(rates['async'], base_async))
        cell['async_vs_base'] = {'mean': m, 'half': h, 'n': n, 'verdict': _verdict(m, h)}
    return cell


def report(summaries: list[dict], planned: int | None = None, name: str | None = None
           ) -> dict:
    """The study's report from its run summaries: ``{'markdown': text, 'numbers': dict}``.

    Per preset, protocol and layout: each condition's final evaluated success (the last
    evaluation point, A-E, learning off) over seeds; Async - best single module (paired over
    seeds); the thesis test, M_vi and M_pl trained inside Async and evaluated alone minus the
    same module trained alone (paired over seeds, the same evaluation draws). Each with a 95%
    t-interval over seeds; and per preset and protocol the per-layout means aggregated over
    layouts (a t-interval over layouts), with the counts of layouts above and below.
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
                               'groups': []}
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
        for key in ('async_best', 'thesis_view', 'thesis_place', 'view_innate',
                    'async_vs_base'):
            per = [c[key]['mean'] for c in pool.values() if key in c]
            if per:
                m, h, n = _ci(per)
                verdicts = [c[key].get('verdict', '') for c in pool.values() if key in c]
                agg[key] = {'mean': m, 'half': h, 'layouts': n, 'verdict': _verdict(m, h),
                            'above': verdicts.count('above'), 'below': verdicts.count('below'),
                            'unresolved': verdicts.count('')}
        conds = list(dict.fromkeys(c for cell in cells.values() for c in cell['conditions']))
        from clis_modules.core.plugin import condition_order
        conds.sort(key=condition_order)
        for c in conds:
            m, h, n = _ci([cell['conditions'][c]['mean'] for cell in pool.values()
                           if c in cell['conditions']])
            agg.setdefault('conditions', {})[c] = {'mean': m, 'half': h, 'layouts': n}
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


def _divergence_lines(numbers: dict) -> list[str]:
    """The report's section on the divergence guard (clis_learner.core.guard)."""
    out = ['', '## Divergence', '',
           'Runs in which the divergence guard reported a module (its value beyond 10 r_max / '
           '(1 - gamma_i), or a non-finite update), of the runs whose summary records it; a run '
           'summarised before the guard existed does not (docs/results.md#divergence).', '',
           _row(['preset', 'protocol', 'runs', 'recorded', 'diverged', 'by condition']),
           '|---|---|---|---|---|---|']
    for g in numbers['groups']:
        d = g.get('diverged') or {'runs': 0, 'recorded': 0, 'diverged': 0, 'conditions': {}}
        by = ', '.join(f'{c} {n}/{k}' for c, (n, k) in d['conditions'].items() if n)
        out.append(_row([g['preset'], g['protocol'], str(d['runs']), str(d['recorded']),
                         str(d['diverged']) if d['recorded'] else '-', by or '-']))
    return out


def _finite(obj: Any) -> Any:
    """NaN as None (JSON)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_finite(v) for v in obj]
    return obj


def _pm(d: Mapping[str, Any] | None, sign: bool = False) -> str:
    if not d or d.get('mean') is None or not math.isfinite(d['mean']):
        return 'n/a'
    s = f'{d["mean"]:+.1f}' if sign else f'{d["mean"]:.1f}'
    h = d.get('half')
    return s + (f' ± {h:.1f}' if h is not None and math.isfinite(h) else '')


def _mark(d: Mapping[str, Any] | None) -> str:
    v = (d or {}).get('verdict', '')
    return {'above': ' **above**', 'below': ' **below**'}.get(v, '')


def _counts(a: Mapping[str, Any] | None, over: str = 'all') -> str:
    if not a:
        return 'n/a'
    return (f'{a["above"]} above, {a["below"]} below, {a["unresolved"]} not resolved; '
            f'over {_layouts(a["layouts"], over)} {_pm(a, sign=True)}{_mark(a)}')


#: The differences of the report: key, column title.
_DIFFS = (('async_best', 'Async - best single'), ('thesis_view', 'M_vi in Async, alone - View'),
          ('thesis_place', 'M_pl in Async, alone - Place'),
          ('async_vs_base', 'Async - Async without the option'))


def _row(cells: list[str]) -> str:
    """A Markdown table row."""
    return '| ' + ' | '.join(cells) + ' |'


def _layouts(n: int, over: str = 'all') -> str:
    kind = 'generated ' if over == 'generated' else ''
    return f'{n} {kind}layout{"" if n == 1 else "s"}'


def _markdown(numbers: dict) -> str:
    title = f'# Study report: {numbers["name"]}' if numbers.get('name') else '# Study report'
    out = [title, '',
           f'{numbers["runs"]} runs' + (f' of {numbers["planned"]} planned'
                                        if numbers['planned'] else '') + '. '
           'Final evaluated success: the successes from A-E at the last evaluation point '
           '(learning off), in %. Differences in points, paired over seeds: Async - best '
           'single module (the single module with the highest mean on that layout); the '
           'thesis test, M_vi (M_pl) trained inside Async and evaluated alone minus View '
           '(Place) trained alone, on the same evaluation draws. ± is the half-width of the '
           '95% t-interval over seeds (none below 3 seeds); **above** / **below**: that '
           'interval excludes 0 (for Async above: its interval against every single module). '
           'Over layouts: the mean of the per-layout values, ± its 95% t-interval over '
           'layouts (**above** / **below** likewise), over the generated layouts where there '
           'are any (the layouts read from files, designed by hand, are in the tables but not '
           'in the aggregate), else over all. The summary counts the layouts on which each '
           'difference is above, below or not resolved, among the same layouts.', '',
           '## Summary', '']
    diffs = [(k, t) for k, t in _DIFFS if any(k in g['aggregate'] for g in numbers['groups'])]
    out += [_row(['preset', 'protocol', 'layouts'] + [t for _, t in diffs]),
            '|---|---|---|' + '---|' * len(diffs)]
    for g in numbers['groups']:
        a = g['aggregate']
        out.append(_row([g['preset'], g['protocol'], str(len(g['layouts']))]
                        + [_counts(a.get(k), a['over']) for k, _ in diffs]))
    for g in numbers['groups']:
        conds = g['conditions']
        here = [(k, t) for k, t in _DIFFS if k in g['aggregate']]
        out += ['', f'## Preset {g["preset"]}, protocol {g["protocol"]}', '']
        if g.get('singles_from'):
            out += [f'The single modules are the runs of preset {g["singles_from"]} (the '
                    'option changes only how modules are chosen: a single-module run is the '
                    'same run); the last column is this Async minus the Async of '
                    f'{g["singles_from"]}, paired over seeds.', '']
        out += [_row(['layout', 'goal hidden', 'seeds'] + conds + [t for _, t in here]),
                '|---|---|---|' + '---|' * (len(conds) + len(here))]
        for name, c in g['layouts'].items():
            cells = [_pm(c['conditions'].get(k)) for k in conds]
            for k, _ in here:
                best = f' ({c[k]["best"]})' if k == 'async_best' and k in c else ''
                cells.append(f'{_pm(c.get(k), True)}{best}{_mark(c.get(k))}')
            out.append(_row([name, f'{100 * c["hidden_share"]:.1f}%', str(len(c['seeds']))]
                            + cells))
        a = g['aggregate']
        cells = ([_pm(a.get('conditions', {}).get(k)) for k in conds]
                 + [_pm(a.get(k), True) + _mark(a.get(k)) for k, _ in here])
        out.append(_row([f'over {_layouts(a["n_layouts"], a["over"])}', '', ''] + cells))
    out += _divergence_lines(numbers)
    return '\n'.join(out) + '\n'


def _draw(numbers: dict, out: Path) -> list[str]:
    """Draw the figures the numbers allow; remove those they do not (a figure of an earlier
    report is not this one's). Returns the names of the figures drawn."""
    from clis_app.study_figures import ForestRow, forest_plot, hidden_scatter
    drawn = []
    panels: dict[str, list] = {}
    for g in numbers['groups']:
        rows = panels.setdefault(g['protocol'], [])
        for name, c in g['layouts'].items():
            ab = c.get('async_best')
            if ab and ab['mean'] is not None:
                rows.append(ForestRow(name, ab['mean'], _nan(ab['half']), g['preset']))
        a = g['aggregate'].get('async_best')
        if a and a['mean'] is not None and a['layouts'] >= 3:      # an aggregate, not a copy
            label = ('over generated layouts' if g['aggregate']['over'] == 'generated'
                     else 'over layouts')
            rows.append(ForestRow(label, a['mean'], _nan(a['half']), g['preset'],
                                  aggregate=True))
    panels = {k: v for k, v in panels.items() if v}
    if panels:
        forest_plot(panels, out / 'forest.png',
                    'Async - best single module: final evaluated success, mean ± 95% CI '
                    'over seeds, per layout', 'Async - best single [points]')
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

        from clis_app.study_figures import layout_gallery
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

