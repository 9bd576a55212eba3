"""The study report's text: ``report.md`` from the numbers of :func:`clis_app.study.report.
report` (the tables of Async against the single modules, of the thesis test, of the final
success over layouts, per preset and protocol, and of the divergence guard's counts).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
import math
from typing import Any


def _order(conditions: Iterable[str]) -> list[str]:
    from clis_modules.core.plugin import condition_order
    return sorted(conditions, key=condition_order)


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


def _num(v: Any) -> float:
    return math.nan if v is None else float(v)


def _pm(d: Mapping[str, Any] | None, sign: bool = False) -> str:
    if not d or not math.isfinite(_num(d.get('mean'))):
        return 'n/a'
    s = f'{d["mean"]:+.1f}' if sign else f'{d["mean"]:.1f}'
    h = _num(d.get('half'))
    return s + (f' ± {h:.1f}' if math.isfinite(h) else '')


def _rate_pm(d: Mapping[str, Any] | None) -> str:
    """A success rate: its mean and clipped interval, ``28.4 [0.0, 75.6]``."""
    if not d or not math.isfinite(_num(d.get('mean'))):
        return 'n/a'
    lo, hi = _num(d.get('low')), _num(d.get('high'))
    return f'{d["mean"]:.1f}' + (f' [{lo:.1f}, {hi:.1f}]' if math.isfinite(lo) else '')


def _below(d: Mapping[str, Any] | None) -> str:
    n = (d or {}).get('below_innate')
    return f'{n[0]}/{n[1]}' if n else 'n/a'


def _mark(d: Mapping[str, Any] | None) -> str:
    v = (d or {}).get('verdict', '')
    return {'above': ' **above**', 'below': ' **below**'}.get(v, '')


def _counts(a: Mapping[str, Any] | None) -> str:
    """An aggregate's mean ± interval over layouts, with the counts of layouts."""
    if not a:
        return 'n/a'
    return (f'{_pm(a, sign=True)}{_mark(a)} ({a["above"]} above, {a["below"]} below, '
            f'{a["unresolved"]} not resolved)')


def _all_counts(a: Mapping[str, Any] | None) -> str:
    if not a:
        return 'n/a'
    over = ('**above**' if a['verdict'] == 'above' else 'not above' if a.get('interval')
            else 'no interval')
    return f'on {a["above"]} of {a["layouts"]}; over layouts: {over}'


#: The differences against the best single module: key, column title.
_BEST = (('async_best', 'Async - best single, in-sample'),
         ('async_best_loo', 'Async - best single, leave one out'))


#: The thesis test: key, column title.
_THESIS = (('thesis_view', 'M_vi in Async, alone - View'),
           ('thesis_place', 'M_pl in Async, alone - Place'))


_BASE = ('async_vs_base', 'Async - Async without the option')


def _row(cells: list[str]) -> str:
    """A Markdown table row."""
    return '| ' + ' | '.join(cells) + ' |'


def _head(titles: list[str]) -> list[str]:
    return [_row(titles), '|' + '---|' * len(titles)]


def _layouts(n: int, over: str = 'all') -> str:
    kind = 'generated ' if over == 'generated' else ''
    return f'{n} {kind}layout{"" if n == 1 else "s"}'


def _pooled(a: Mapping[str, Any]) -> str:
    return f'{a["n_layouts"]} generated' if a['over'] == 'generated' else f'{a["n_layouts"]}, all'


def _chosen(c: Mapping[str, Any]) -> str:
    """The modules the leave-one-out choice took, most often first: ``(view 4, innate 1)``."""
    picks = list(c.get('chosen', {}).values())
    order = _order(dict.fromkeys(picks))
    ranked = sorted(order, key=lambda m: (-picks.count(m), order.index(m)))
    return ' (' + ', '.join(f'{m} {picks.count(m)}' for m in ranked) + ')' if picks else ''


_INTRO = (
    'Final evaluated success: the successes from A-E at the last evaluation point (learning '
    'off), in %, the mean over seeds and [the 95% t-interval over seeds, clipped to [0, 100]] '
    '(none below 3 seeds). "below innate" n/k: n of the condition\'s k runs (seeds) end below '
    "Innate's mean on that layout. Differences in points, paired over seeds (a seed's runs "
    'share their evaluation starts and noise), ± the half-width of the 95% t-interval over '
    'seeds: Async - each single module; Async - best single, in-sample: the single module '
    "with the highest mean over the layout's seeds, compared on those same seeds (the choice "
    'favours the comparator); Async - best single, leave one out: for each seed, the single '
    'module with the highest mean over the other seeds, compared on this seed (the modules '
    'chosen, with how many seeds each); the thesis test, M_vi (M_pl) trained inside Async and '
    'evaluated alone minus View (Place) trained alone, on the same evaluation draws. '
    "**above** / **below**: that difference's interval excludes 0. Async is above every "
    'single module where its interval against each single module is above 0. Over layouts: '
    'the mean of the per-layout values, with its 95% t-interval over layouts (**above** / '
    '**below** likewise; above every single module when each of those intervals is above 0), '
    'over the generated layouts where there are any (the layouts read from files, designed '
    'by hand, are in the tables but not in the aggregate), else over all ("pooled"). The '
    'summaries count the layouts on which each difference is above, below or not resolved, '
    'among the pooled layouts.')


def _markdown(numbers: dict) -> str:
    title = f'# Study report: {numbers["name"]}' if numbers.get('name') else '# Study report'
    read = (f'{numbers["runs"]} run summaries read' + (f' of {numbers["planned"]} runs planned'
                                                      if numbers['planned'] else '') + '.')
    if numbers.get('outside_plan'):
        n = numbers['outside_plan']
        read += (f' {n} more summar{"y" if n == 1 else "ies"} in the runs folder '
                 f'{"is" if n == 1 else "are"} of runs outside the plan, not reported.')
    out = [title, '', read, '', _INTRO]
    groups = numbers['groups']
    singles = _order(dict.fromkeys(c for g in groups for c in g['aggregate'].get(
        'async_minus', {})))
    best = [(k, t) for k, t in _BEST if any(k in g['aggregate'] for g in groups)]
    base = [_BASE] if any(_BASE[0] in g['aggregate'] for g in groups) else []
    if singles or best or base:
        out += ['', '## Summary: Async against the single modules', '']
        out += _head(['preset', 'protocol', 'layouts', 'pooled', 'Async above every single']
                     + [f'Async - {c}' for c in singles] + [t for _, t in best + base])
        for g in groups:
            a = g['aggregate']
            out.append(_row([g['preset'], g['protocol'], str(len(g['layouts'])), _pooled(a),
                             _all_counts(a.get('async_all'))]
                            + [_counts(a.get('async_minus', {}).get(c)) for c in singles]
                            + [_counts(a.get(k)) for k, _ in best + base]))
    thesis = [(k, t) for k, t in _THESIS if any(k in g['aggregate'] for g in groups)]
    if thesis:
        out += ['', '## Summary: the thesis test', '']
        out += _head(['preset', 'protocol', 'layouts', 'pooled'] + [t for _, t in thesis])
        for g in groups:
            a = g['aggregate']
            out.append(_row([g['preset'], g['protocol'], str(len(g['layouts'])), _pooled(a)]
                            + [_counts(a.get(k)) for k, _ in thesis]))
    conds = _order(dict.fromkeys(c for g in groups for c in g['conditions']))
    out += ['', '## Summary: final evaluated success over layouts', '']
    out += _head(['preset', 'protocol', 'pooled'] + conds)
    for g in groups:
        a = g['aggregate']
        cells = []
        for c in conds:
            d = a.get('conditions', {}).get(c)
            cells.append('n/a' if not d else _rate_pm(d) + (
                f'; {_below(d)} below innate' if d.get('below_innate') else ''))
        out.append(_row([g['preset'], g['protocol'], _pooled(a)] + cells))
    for g in groups:
        out += _group_lines(g)
    out += _divergence_lines(numbers)
    return '\n'.join(out) + '\n'


def _group_lines(g: dict) -> list[str]:
    """The section of one preset and protocol: final success and differences per layout."""
    conds, a = g['conditions'], g['aggregate']
    out = ['', f'## Preset {g["preset"]}, protocol {g["protocol"]}', '']
    if g.get('singles_from'):
        out += [f'The single modules are the runs of preset {g["singles_from"]} (the '
                'option changes only how modules are chosen: a single-module run is the '
                'same run); the last column is this Async minus the Async of '
                f'{g["singles_from"]}, paired over seeds.', '']
    below = [c for c in conds if c != 'innate' and any(
        'below_innate' in cell['conditions'].get(c, {}) for cell in g['layouts'].values())]
    titles = ['layout', 'goal hidden', 'seeds']
    for c in conds:
        titles += [c] + ([f'{c} below innate'] if c in below else [])
    out += ['Final evaluated success [%]:', ''] + _head(titles)
    last = f'over {_layouts(a["n_layouts"], a["over"])}'
    for name, cell in list(g['layouts'].items()) + [(last, None)]:
        src = cell['conditions'] if cell else a.get('conditions', {})
        cells = ([name, f'{100 * cell["hidden_share"]:.1f}%', str(len(cell['seeds']))]
                 if cell else [name, '', ''])
        for c in conds:
            cells += [_rate_pm(src.get(c))] + ([_below(src.get(c))] if c in below else [])
        out.append(_row(cells))
    singles = list(a.get('async_minus', {}))
    here = [(k, t) for k, t in _BEST + _THESIS + (_BASE,) if k in a]
    if not (singles or here):
        return out
    titles = (['layout'] + [f'Async - {c}' for c in singles]
              + (['Async above every single'] if singles else []) + [t for _, t in here])
    out += ['', 'Differences [points]:', ''] + _head(titles)
    for name, cell in list(g['layouts'].items()) + [(last, None)]:
        src = cell or a
        cells = [name]
        for c in singles:
            d = src.get('async_minus', {}).get(c)
            cells.append(_pm(d, True) + _mark(d))
        if singles:
            v = (src.get('async_all') or {}).get('verdict', '')
            cells.append('**above**' if v == 'above' else ('-' if src.get('async_all')
                                                             else 'n/a'))
        for k, _ in here:
            d = src.get(k)
            note = ''
            if cell and d and k == 'async_best':
                note = f' ({d["best"]})'
            elif cell and d and k == 'async_best_loo':
                note = _chosen(d)
            cells.append(f'{_pm(d, True)}{note}{_mark(d)}')
        out.append(_row(cells))
    return out
