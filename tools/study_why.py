"""Diagnostics of a ``clis study`` folder beyond its report (docs/cooperation.md).

    python tools/study_why.py studies/layouts camera --png docs/figures/study_camera.png
    python tools/study_why.py studies/layouts starts
    python tools/study_why.py studies/layouts layouts
    python tools/study_why.py studies/layouts selection
    python tools/study_why.py studies/layouts practice

``camera``: on config/arena.yaml, each condition's final evaluated success and Async - best
single (chosen on the same seeds, and on the other seeds: clis_app.study.report) against the
destination's detection range (``sensors.destination_range`` of the presets' ``sim_set``; a
run without it sees the destination up to ``camera_range``), per protocol; with ``--png`` the
same as a figure.

``starts``: the final evaluated success from each start A-E (A-C: straight line clear; D: a
short obstacle across it; E: the destination hidden), per protocol and condition, mean over
the generated layouts of each layout's mean over seeds: where Async gains or loses. Then,
per protocol and condition, how many runs end at or below their first evaluation (episode 0)
and how many end below Innate's mean on their layout.

``layouts``: across the generated layouts, per protocol, how Async - best single (chosen on
the same seeds, and on the other seeds) goes with the layout's hidden share, Innate's success
and View - Innate (Pearson r with its 95% interval by Fisher's z).

``selection``: at the end of learning, the arbiter's Pr(i | x_0) of (3) at each start A-E
(the draw of an evaluation episode there, 5 sensor-noise draws), per protocol, mean over the
generated layouts: which module Async chooses where. It loads each Async run's checkpoint
from ``DIR/work`` and writes the numbers to ``DIR/selection.json`` (committed: without
``DIR/work``, it prints from that file).

``practice``: how often the view module acts in a learning episode that starts where the
innate policy fails (the straight line to the goal crosses a short obstacle, as from D, or a
tall one hides the goal, as from E), View alone against inside Async, protocol ``wander``,
on the first generated layouts (``--layouts``, ``--seeds``). It reruns those learning runs
(seed for seed the study's: evaluation does not touch learning), recording where each
episode starts, and writes ``DIR/practice.json`` (committed: ``--from-json`` prints it).

Reads ``DIR/runs`` and ``DIR/report.json`` (``clis study --report-only --out DIR`` writes
it); prints Markdown tables. A success rate is printed as its mean and [its 95% t-interval,
clipped to [0, 100]]; a difference as its mean ± the half-width of its interval.
"""

from __future__ import annotations

import argparse
from collections import defaultdict
import json
import math
from pathlib import Path
import sys

import numpy as np

CONDITIONS = ('innate', 'view', 'place', 'async')
PROTOCOLS = ('wander', 'starts', 'random')
STARTS = 'ABCDE'


def _summaries(out: Path) -> list[dict]:
    from clis_app.study.report import study_summaries
    return study_summaries(out)[0]


def _ci(values: list[float]) -> tuple[float, float]:
    """Mean and half-width of the 95% t-interval (NaN below 3 values)."""
    from clis_app.experiments.claims import mean_ci
    return mean_ci(values)


def _pm(m: float, h: float, sign: bool = False) -> str:
    if not math.isfinite(m):
        return 'n/a'
    s = f'{m:+.1f}' if sign else f'{m:.1f}'
    return s + (f' ± {h:.1f}' if math.isfinite(h) else '')


def _rate_pm(values: list[float]) -> str:
    """A success rate in %: its mean and [95% t-interval clipped to [0, 100]]."""
    from clis_app.study.report import rate_interval
    r = rate_interval(values)
    if not math.isfinite(r['mean']):
        return 'n/a'
    return f'{r["mean"]:.1f}' + (f' [{r["low"]:.1f}, {r["high"]:.1f}]'
                                 if math.isfinite(r['low']) else '')


def _rate(d: dict) -> float:
    return 100.0 * d['final']['reached'] / d['final']['n']


def camera(out: Path, png: Path | None) -> None:
    from clis_app.study.report import leave_one_out_best, rate_interval
    from cr_sim.core.sim import load_sim_params
    default = load_sim_params().sensors.camera_range
    cells: dict[tuple[str, float], dict[str, dict[int, float]]] = defaultdict(
        lambda: defaultdict(dict))
    for d in _summaries(out):
        if d['arena'] != 'arena' or d['settings'].get('preset') != 'improved' \
                or d['settings'].get('set'):
            continue
        rng = d['settings'].get('sim_set', {}).get('sensors.destination_range') or default
        cells[(d['protocol'], float(rng))][d['condition']][d['seed']] = _rate(d)
    ranges = sorted({r for _, r in cells})
    print(f'Destination range on config/arena.yaml (the landmarks keep {default:g} m), '
          'improved, final evaluated success [%], mean [95% CI over seeds, clipped to '
          '[0, 100]]; Async - best single paired over seeds, the best chosen on the same seeds '
          '(in-sample) and on the other seeds (leave one out):\n')
    print('| protocol | destination range [m] | seeds | ' + ' | '.join(
        c.capitalize() for c in CONDITIONS) + ' | Async - best single, in-sample | '
        'Async - best single, leave one out |')
    print('|---|---|---|' + '---|' * (len(CONDITIONS) + 2))
    curves: dict[str, dict[str, list]] = defaultdict(lambda: defaultdict(list))
    for proto in PROTOCOLS:
        for r in ranges:
            c = cells.get((proto, r))
            if not c:
                continue
            stats = {k: rate_interval(list(c[k].values())) for k in CONDITIONS if k in c}
            singles = [k for k in ('innate', 'view', 'place') if k in stats]
            diff = loo = (math.nan, math.nan)
            if 'async' in c and singles:
                best = max(singles, key=lambda k: (stats[k]['mean'], -singles.index(k)))
                diff = _ci([c['async'][s] - c[best][s] for s in c['async'] if s in c[best]])
                loo = _ci([v for _, v in leave_one_out_best(
                    c['async'], {k: c[k] for k in singles}).values()])
            seeds = len(c.get('async', {}))
            print(f'| {proto} | {r:g} | {seeds} | ' + ' | '.join(
                _rate_pm(list(c[k].values())) if k in stats else 'n/a' for k in CONDITIONS)
                + f' | {_pm(*diff, sign=True)} | {_pm(*loo, sign=True)} |')
            for k, st in stats.items():
                curves[proto][k].append((r, st['mean'], st['low'], st['high']))
    if png is not None:
        _camera_figure(curves, png, default)


def _camera_figure(curves: dict, png: Path, default: float) -> None:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    import matplotlib.ticker
    colours = {'innate': 'black', 'view': 'tab:purple', 'place': 'tab:green',
               'async': 'tab:red'}
    fig, axes = plt.subplots(1, len(curves), figsize=(4.2 * len(curves), 3.8), sharey=True,
                             squeeze=False)
    for ax, (proto, by) in zip(axes[0], curves.items()):
        for k, pts in by.items():
            x, m, lo, hi = (np.array(v, float) for v in zip(*pts))
            err = np.nan_to_num(np.stack([m - lo, hi - m]))        # the clipped interval
            ax.errorbar(x, m, yerr=err, color=colours[k], marker='o', ms=4,
                        capsize=3, label=k.capitalize())
        ax.set_xscale('log')
        ax.set_xticks([1.0, 1.5, 2.0, 5.0], ['1', '1.5', '2', '5'])
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set_title(f'protocol {proto}', fontsize=10)
        ax.set_xlabel('destination detection range [m]', fontsize=9)
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel('final evaluated success [%]', fontsize=9)
    axes[0][0].legend(fontsize=8, loc='lower left')
    fig.suptitle(f'config/arena.yaml, improved: the destination seen up to the range on x, '
                 f'the landmarks up to {default:g} m (mean and 95% CI over 5 seeds, clipped '
                 'to [0, 100])', fontsize=9)
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=110, bbox_inches='tight')
    print(f'\nwrote {png}', file=sys.stderr)


def starts(out: Path) -> None:
    from clis_app.study.report import below_level
    # (protocol, condition) -> start -> per-layout means
    per: dict[tuple[str, str], dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    runs: dict[tuple, list[dict]] = defaultdict(list)
    for d in _summaries(out):
        if d['preset'] == 'improved' and d['settings'].get('layout_seed') is not None:
            runs[(d['protocol'], d['condition'], d['arena'])].append(d)
    for (proto, cond, _), rows in runs.items():
        last = [r['eval_curve'][-1] for r in rows]
        for s in STARTS:
            per[(proto, cond)][s].append(
                float(np.mean([100 * p[f'reached_{s}'] / (p['n'] / len(STARTS)) for p in last])))
    print('Final evaluated success from each start [%], improved, mean over the generated '
          'layouts (each layout: its mean over seeds) [95% CI over layouts, clipped to '
          '[0, 100]]:\n')
    print('| protocol | condition | layouts | ' + ' | '.join(STARTS) + ' |')
    print('|---|---|---|' + '---|' * len(STARTS))
    for proto in PROTOCOLS:
        for cond in CONDITIONS:
            by = per.get((proto, cond))
            if not by:
                continue
            print(f'| {proto} | {cond} | {len(by["A"])} | '
                  + ' | '.join(_rate_pm(by[s]) for s in STARTS) + ' |')
    print('\nRuns on the generated layouts (improved) that end at or below their first '
          "evaluation (episode 0, before learning), and that end below Innate's mean on "
          'their layout:\n')
    print('| protocol | condition | runs | end at or below their first evaluation | '
          "end below Innate's mean |")
    print('|---|---|---|---|---|')
    for proto in PROTOCOLS:
        for cond in CONDITIONS:
            rows = [(a, r) for (p, c, a), rs in runs.items() if (p, c) == (proto, cond)
                    for r in rs]
            if not rows:
                continue
            flat = sum(r['eval_curve'][-1]['reached'] <= r['eval_curve'][0]['reached']
                       for _, r in rows)
            below = 0
            if cond != 'innate':
                for a in {a for a, _ in rows}:
                    level = float(np.mean([_rate(r) for r in runs[(proto, 'innate', a)]]))
                    below += below_level([_rate(r) for b, r in rows if b == a], level)[0]
            print(f'| {proto} | {cond} | {len(rows)} | {flat} | '
                  + ('-' if cond == 'innate' else str(below)) + ' |')


def _pearson(x: list[float], y: list[float]) -> str:
    x, y = np.asarray(x, float), np.asarray(y, float)
    ok = np.isfinite(x) & np.isfinite(y)
    x, y = x[ok], y[ok]
    if len(x) < 4 or np.ptp(x) == 0 or np.ptp(y) == 0:
        return 'n/a'
    r = float(np.corrcoef(x, y)[0, 1])
    z, se = math.atanh(r), 1.0 / math.sqrt(len(x) - 3)
    lo, hi = math.tanh(z - 1.96 * se), math.tanh(z + 1.96 * se)
    return f'{r:+.2f} [{lo:+.2f}, {hi:+.2f}]'


def layouts(out: Path) -> None:
    report = json.loads((out / 'report.json').read_text())
    print('Across the generated layouts (improved): Pearson r of Async - best single (chosen '
          'on the same seeds: in-sample; on the other seeds: leave one out) with each '
          "layout's property [95% CI, Fisher's z]:\n")
    print('| protocol | best single | layouts | hidden share | Innate | View - Innate |')
    print('|---|---|---|---|---|---|')
    for g in report['groups']:
        if g['preset'] != 'improved':
            continue
        for key, how in (('async_best', 'in-sample'), ('async_best_loo', 'leave one out')):
            cells = [c for c in g['layouts'].values() if c.get('layout_seed') is not None
                     and c.get(key) and c[key]['mean'] is not None]
            y = [c[key]['mean'] for c in cells]
            hidden = [c['hidden_share'] for c in cells]
            innate = [(c['conditions'].get('innate') or {}).get('mean', math.nan)
                      for c in cells]
            vi = [(c.get('view_innate') or {}).get('mean', math.nan) for c in cells]
            vi = [math.nan if v is None else v for v in vi]
            innate = [math.nan if v is None else v for v in innate]
            print(f'| {g["protocol"]} | {how} | {len(cells)} | {_pearson(hidden, y)} | '
                  f'{_pearson(innate, y)} | {_pearson(vi, y)} |')


def _start_probs(d: dict, out: Path, draws: int = 5) -> dict[str, list[float]] | None:
    """Pr(i | x_0) at each start of the Async run ``d`` with its checkpoint's parameters."""
    import re

    from clis_app.experiments.runner import Agent
    from clis_base.instants import DecisionClock
    from clis_learner.core.checkpoint import load_checkpoint
    from clis_learner.core.config import load_clis_params, preset_overrides
    from clis_modules.core.decider import Percept
    from cr_sim.core.arena import load_arena
    from cr_sim.core.sim import Simulator, load_sim_params
    label = f'{d["arena"]}/{d["protocol"]}/{d["preset"]}/{d["condition"]}'
    ckpt = out / 'work' / (re.sub(r'[^A-Za-z0-9_.=-]+', '_', label) + f'__s{d["seed"]}.npz')
    if not ckpt.is_file():
        return None
    st = d['settings']
    params = load_clis_params(overrides={**preset_overrides(st['preset']), **st['set']})
    sim_params = load_sim_params(overrides=st['sim_set'])
    arena = load_arena(out / 'arenas' / f'{d["arena"]}.yaml', sim_params.robot.radius)
    agent = Agent(params, d['condition'], arena, np.random.default_rng(0),
                  sim_params.robot.wheel_base)
    load_checkpoint(ckpt, agent.modules)
    agent.stream.clock = DecisionClock([m.period for m in agent.modules],
                                       sim_params.episode.dt)
    agent.selector.explore_now = False                 # as in an evaluation episode
    probs = {}
    for name in arena.start_names:
        rows = []
        for k in range(draws):
            sim = Simulator(arena, sim_params, np.random.default_rng([d['seed'], 5, k]))
            sim.reset(start=name)
            percept = Percept(0.0, *sim.sense_all())
            agent.selector.begin_episode(0.0)
            agent.stream.begin_episode()
            agent.stream.instant(0)                     # the draws of the first instant
            for dec in agent.deciders:
                dec.reset()
            agent.selector.on_proposals([dec.decide(percept) for dec in agent.deciders], 0.0)
            rows.append(agent.selector.start_probs)
        probs[name] = np.mean(rows, axis=0).tolist()
    return {'modules': agent.names, 'probs': probs}


def selection(out: Path) -> None:
    saved = out / 'selection.json'
    runs = [d for d in _summaries(out) if d['condition'] == 'async'
            and d['preset'] in ('improved', 'improved+bonus')
            and d['settings'].get('layout_seed') is not None]
    data: dict[str, dict] = {}
    if (out / 'work').is_dir():
        for d in runs:
            key = f'{d["arena"]}/{d["protocol"]}/{d["preset"]}/s{d["seed"]}'
            got = _start_probs(d, out)
            if got is not None:
                data[key] = got
        tmp = saved.with_suffix('.json.tmp')
        tmp.write_text(json.dumps(data, indent=1, sort_keys=True) + '\n')
        tmp.replace(saved)
    elif saved.is_file():
        data = json.loads(saved.read_text())
    if not data:
        print(f'study_why: no checkpoints in {out}/work and no {saved}', file=sys.stderr)
        return
    # (preset, protocol) -> start -> module -> per-layout means
    per: dict = defaultdict(lambda: defaultdict(lambda: defaultdict(lambda: defaultdict(list))))
    for key, got in data.items():
        arena, proto, preset, _ = key.split('/')
        for start, p in got['probs'].items():
            for name, v in zip(got['modules'], p):
                per[(preset, proto)][start][name][arena].append(v)
    print("At the end of learning, Async's Pr(i | x_0) at each start [%], mean over the "
          'generated layouts (each: its mean over seeds) ± 95% CI over layouts:\n')
    print('| preset | protocol | module | ' + ' | '.join(STARTS) + ' |')
    print('|---|---|---|' + '---|' * len(STARTS))
    for (preset, proto) in sorted(per, key=lambda k: (k[0], PROTOCOLS.index(k[1]))):
        by = per[(preset, proto)]
        for name in ('innate', 'view', 'place'):
            cells = [_pm(*_ci([100 * float(np.mean(v)) for v in by[s][name].values()]))
                     for s in STARTS]
            print(f'| {preset} | {proto} | {name} | ' + ' | '.join(cells) + ' |')
    print(f'\n({len(data)} runs; {saved})', file=sys.stderr)


def _practice_run(job: tuple[str, str, int, int, str]) -> dict:
    """One learning run of ``condition`` on ``arena`` (wander, improved): per episode, whether
    it started where the straight line to the goal is blocked, who acted, and the outcome."""
    arena_path, condition, seed, episodes, label = job
    from clis_app.experiments.runner import Agent, run_episode
    from clis_learner.core.config import load_clis_params, preset_overrides
    from cr_sim.core.arena import load_arena
    from cr_sim.core.geometry import segments_blocked
    from cr_sim.core.sim import Simulator, load_sim_params
    from cr_sim.core.starts import draw_start
    params = load_clis_params(overrides=preset_overrides('improved'))
    sim_params = load_sim_params()
    arena = load_arena(arena_path, sim_params.robot.radius)
    sim = Simulator(arena, sim_params, np.random.default_rng([seed, 0]))
    start_rng = np.random.default_rng([seed, 1])
    agent = Agent(params, condition, arena, np.random.default_rng([seed, 2]),
                  sim_params.robot.wheel_base)
    d = arena.destination
    boxes = arena.box_array()
    starts: list[tuple[float, float]] = []
    reset = sim.reset

    def recording_reset(*args, **kwargs):
        obs = reset(*args, **kwargs)
        starts.append(tuple(float(v) for v in sim.pose[:2]))
        return obs
    sim.reset = recording_reset
    counts = {'episodes': episodes, 'hard': 0, 'view_hard': 0, 'reached_hard': 0}
    for _ in range(episodes):
        start, heading = draw_start('wander', arena, start_rng)
        row = run_episode(sim, agent, start, heading, learn=True)
        x, y = starts[-1]
        if segments_blocked(x, y, np.array([[d.x, d.y]]), boxes)[0]:
            counts['hard'] += 1
            counts['view_hard'] += row['behaviour'] == 'view'
            counts['reached_hard'] += int(row['reached'])
    return {'label': label, 'condition': condition, 'seed': seed, **counts}


def practice(out: Path, n_layouts: int, seeds: int, episodes: int, from_json: bool) -> None:
    saved = out / 'practice.json'
    if from_json:
        data = json.loads(saved.read_text())
    else:
        from concurrent.futures import ProcessPoolExecutor
        import os
        names = sorted(p.stem for p in (out / 'arenas').glob('gen-s*.yaml'))[:n_layouts]
        jobs = [(str(out / 'arenas' / f'{a}.yaml'), c, s, episodes, a)
                for a in names for c in ('view', 'async') for s in range(seeds)]
        with ProcessPoolExecutor(os.cpu_count() or 1) as pool:
            data = list(pool.map(_practice_run, jobs))
        tmp = saved.with_suffix('.json.tmp')
        tmp.write_text(json.dumps(data, indent=1) + '\n')
        tmp.replace(saved)
    layouts = sorted({d['label'] for d in data})
    n_seeds = len({d['seed'] for d in data})
    n_eps = data[0]['episodes']
    print(f'Learning episodes that start where the straight line to the goal is blocked '
          f'(protocol wander, improved; {len(layouts)} generated layouts x {n_seeds} seeds x '
          f'{n_eps} episodes), per run, mean ± 95% CI over runs:\n')
    print('| condition | episodes from a blocked start | of them, the view module acting | '
          'the view module acting from a blocked start | success from a blocked start |')
    print('|---|---|---|---|---|')
    for cond in ('view', 'async'):
        runs = [d for d in data if d['condition'] == cond]
        n_hard = [d['hard'] for d in runs]
        view_share = [100 * d['view_hard'] / max(d['hard'], 1) for d in runs]
        view_hard = [d['view_hard'] for d in runs]
        succ = [100 * d['reached_hard'] / max(d['hard'], 1) for d in runs]
        print(f'| {cond} | {_pm(*_ci(n_hard))} | {_pm(*_ci(view_share))}% | '
              f'{_pm(*_ci(view_hard))} | {_pm(*_ci(succ))}% |')
    print(f'\n({saved})', file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('out', type=Path, metavar='DIR', help='a clis study folder')
    p.add_argument('what', choices=('camera', 'starts', 'layouts', 'selection', 'practice'))
    p.add_argument('--png', type=Path, help='camera: also draw the figure here')
    p.add_argument('--layouts', type=int, default=4, help='practice: generated layouts')
    p.add_argument('--seeds', type=int, default=3, help='practice: seeds per layout')
    p.add_argument('--episodes', type=int, default=1000, help='practice: learning episodes')
    p.add_argument('--from-json', action='store_true',
                   help='practice: print DIR/practice.json instead of running')
    args = p.parse_args(argv)
    if not (args.out / 'plan.json').is_file():
        print(f'study_why: {args.out}: not a study folder (no plan.json)', file=sys.stderr)
        return 2
    {'camera': lambda: camera(args.out, args.png), 'starts': lambda: starts(args.out),
     'layouts': lambda: layouts(args.out),
     'selection': lambda: selection(args.out),
     'practice': lambda: practice(args.out, args.layouts, args.seeds, args.episodes,
                                  args.from_json)}[args.what]()
    return 0


if __name__ == '__main__':
    sys.exit(main())
