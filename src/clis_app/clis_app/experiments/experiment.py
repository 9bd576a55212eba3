"""``clis experiment``: the paper's experiments (Fig. 3-5), headless, over several seeds.

Each (condition, seed) is one *run*: ``episodes`` learning episodes driven by the headless
runner (:mod:`clis_app.experiments.runner`), then evaluation episodes from each start point with
learning off. Runs go to parallel worker processes on this machine (``--backend process``) or
to Ray tasks (``--backend ray``: a local Ray instance, or a cluster with ``--address``; see
docs/scale.md); each run's results are written atomically to ``OUT/runs/`` as soon as it
finishes, so an interrupted experiment (Ctrl-C: one line, exit 130) loses only the runs in
flight and ``--resume`` continues it, with either backend; it reuses a saved run only if it was
made with the same settings (spec, parameter hash, arena), else it stops saying what differs.
A run's results are the same whichever backend ran it. At the end the runs are merged into
``episodes.csv``, ``eval.csv``, ``summary.json`` and the figures (``fig3a.png`` ...).

A condition is a name (``innate``, ``view``, ``place``, ``sync``, ``async``) optionally followed
by parameter overrides of ``config/clis.yaml``, ``@key=value`` each, so that variants run side by
side on the same seeds: ``async@common.beta=200`` or ``sync@learner.resample=zoh``. Every
condition runs with ``--preset`` (default ``improved``, the preset that learns; ``paper`` is the
rules exactly as printed, whose values diverge in most runs: the divergence guard,
:mod:`clis_learner.core.guard`, says so in the progress line, the summary and each run's
``diverged`` field).
"""

from __future__ import annotations

import argparse
from functools import partial
import json
import os
from pathlib import Path
import sys
import time
from typing import Any

from clis_learner.core.config import DEFAULT_PRESET
from clis_modules.core.plugin import parse_condition
from cr_sim.core.arena import load_arena
from cr_sim.core.starts import draw_start
import numpy as np

from clis_app import files
from clis_app.cli.errors import fail
from clis_app.cli.help import HelpFormatter
from clis_app.experiments.pool import (  # noqa: F401 - the study's and the tests' names
    Progress,
    RunError,
    _cost,
    _run_all,
    _worker_signals,
    job_costs,
    longest_first,
)
from clis_app.experiments.runner import JobResult, JobSpec

#: Where the runs execute (``--backend``).
BACKENDS = ('process', 'ray')
EPILOG = """\
examples:
  clis experiment --conditions innate,view,place,sync,async --episodes 1000 --seeds 10 \\
      --out results/improved                                  # the improved preset (default)
  clis experiment --preset paper --conditions innate,view,place,sync,async --episodes 1000 \\
      --seeds 10 --out results/paper                          # the paper's rules as printed
  clis experiment --conditions async,async@common.beta=200 --episodes 300 --seeds 3 --out /tmp/b
  clis experiment --figures-only --out results/paper          # redraw from saved runs
  clis experiment --backend ray --conditions async --seeds 20 --out /tmp/r   # local Ray
  clis experiment --backend ray --address HEAD:6379 --seeds 100 --out /tmp/r # a Ray cluster
"""


def parse_variant(spec: str) -> tuple[str, dict[str, Any]]:
    """A variant, a condition with parameter overrides:
    ``'async@common.beta=200@learner.resample=zoh'`` -> ``('async', {...})``. The condition is
    parsed by the one condition parser, :func:`clis_modules.core.plugin.parse_condition`."""
    name, *sets = spec.strip().split('@')
    try:
        parse_condition(name)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f'{exc} (variants as CONDITION@key=value)') from None
    overrides = {}
    for item in sets:
        if '=' not in item:
            raise argparse.ArgumentTypeError(f'override {item!r} in {spec!r} must be key=value')
        key, value = item.split('=', 1)
        overrides[key] = _yaml_scalar(value)
    return name, overrides


def _yaml_scalar(text: str) -> Any:
    import yaml
    return yaml.safe_load(text)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        'experiment', help='run the paper experiments headless and draw Fig. 3-5',
        description=__doc__, epilog=EPILOG, formatter_class=HelpFormatter)
    p.add_argument('--conditions', default='innate,view,place,sync,async',
                   help='comma-separated conditions')
    p.add_argument('--episodes', type=int, default=1000, help='learning episodes per run')
    p.add_argument('--seeds', type=int, default=5, help='number of seeds (0..N-1)')
    p.add_argument('--first-seed', type=int, default=0, help='first seed')
    p.add_argument('--eval-episodes', type=int, default=10,
                   help='evaluation episodes per start point A-E, at the end and at every '
                        'evaluation point')
    p.add_argument('--eval-every', type=int, default=50, metavar='N',
                   help='every N learning episodes (and before the first), evaluate from each '
                        'start A-E with learning off: the Fig. 3a curve (paper Fig. 2 caption; '
                        '0 = off, Fig. 3a from the learning episodes)')
    p.add_argument('--preset', default=DEFAULT_PRESET, choices=presets(),
                   help='parameter preset: config/clis.yaml with the overrides of '
                        'config/clis_PRESET.yaml (default %(default)s: the one that learns, '
                        'beyond the paper); paper = the rules exactly as printed, whose '
                        'values diverge in most runs (docs/results.md)')
    p.add_argument('--ablation', action='store_true',
                   help='with --preset P: also Async with each change of P alone (on the '
                        'paper preset) and with all of them (P:async), on the same seeds')
    p.add_argument('--train-start', default='wander',
                   help="where learning episodes start: 'wander' (the paper: the hand-"
                        "made wander policy moves the robot from where the last episode ended),"
                        " 'starts' (one of A-E, random heading), 'random', or a start name")
    p.add_argument('--block', type=int, default=50,
                   help='episodes per point of the learning curve (50: the paper)')
    p.add_argument('--out', type=Path, required=True, help='output folder')
    p.add_argument('--arena', type=Path, help='arena file (None: config/arena.yaml)')
    p.add_argument('--set', dest='sets', action='append', default=[], metavar='KEY=VALUE',
                   help='override config/clis.yaml for all conditions, e.g. common.beta=2')
    p.add_argument('--sim-set', dest='sim_sets', action='append', default=[],
                   metavar='KEY=VALUE',
                   help='override config/sim.yaml or the body (config/robot.yaml), e.g. '
                        'sensors.ir_noise_sigma=0.0')
    p.add_argument('--workers', type=int, default=os.cpu_count() or 1,
                   help='parallel processes (all cores); with --backend ray and no '
                        '--address, the CPUs of the local Ray instance')
    p.add_argument('--backend', choices=BACKENDS, default='process',
                   help="'process': a pool of worker processes on this machine; "
                        "'ray': Ray tasks (ray.init() starts a local instance bound to "
                        '127.0.0.1; docs/scale.md)')
    p.add_argument('--address', metavar='ADDR',
                   help='with --backend ray: join the running Ray cluster at ADDR (host:port '
                        'printed by `ray start --head`); its workers need this project '
                        'installed (docs/scale.md)')
    p.add_argument('--resume', action='store_true',
                   help='keep the finished runs in OUT/runs (stops if any was made with other '
                        'settings)')
    p.add_argument('--figures-only', action='store_true',
                   help="only merge and draw the runs of OUT (OUT/experiment.json's "
                        'settings; the other flags are not used)')
    p.add_argument('--quiet', action='store_true', help='no progress output')
    p.set_defaults(func=main)


def presets() -> tuple[str, ...]:
    """The parameter presets: ``paper`` (config/clis.yaml) and every config/clis_NAME.yaml."""
    from clis_learner.core.config import PRESET_NAMES
    return PRESET_NAMES()


def ablation_conditions(preset: str, base: str = 'async') -> list[str]:
    """``base`` with each change of ``preset`` alone (its groups,
    :func:`~clis_learner.core.config.preset_groups`) on the paper's parameters:
    ``async@key=value@...``. All changes together is the preset's own ``base`` condition."""
    from clis_learner.core.config import preset_groups
    return [base + ''.join(f'@{k}={v}' for k, v in items.items())
            for items in preset_groups(preset).values()]


def _overrides(items: list[str], flag: str = '--set') -> dict[str, Any]:
    out = {}
    for item in items:
        if '=' not in item:
            raise ValueError(f'{flag} {item!r} must be KEY=VALUE')
        key, value = item.split('=', 1)
        out[key] = _yaml_scalar(value)
    return out


#: ``clis experiment: MESSAGE`` on one line, exit code 2 (:func:`clis_app.cli.errors.fail`)
_fail = partial(fail, 'experiment')


def main(args: argparse.Namespace) -> int:
    """``clis experiment``: validate everything before anything is created in ``--out``."""
    out: Path = args.out
    runs_dir = out / 'runs'
    if args.figures_only:
        return figures_only(out)
    conditions = [c.strip() for c in args.conditions.split(',') if c.strip()]
    if not conditions:
        return _fail('--conditions is empty')
    twice = sorted({c for c in conditions if conditions.count(c) > 1})
    if twice:
        return _fail(f'--conditions lists {", ".join(twice)} more than once (each condition '
                     'is one set of runs; more seeds: --seeds)')
    from clis_learner.core.config import preset_overrides as _preset
    preset_overrides = _preset(args.preset)
    with_preset = [True] * len(conditions)         # the preset applies to the conditions given
    if args.ablation:
        if args.preset == 'paper':
            return _fail('--ablation toggles the changes of a preset beyond the paper: not '
                         'with --preset paper (e.g. --preset improved, the default)')
        singles = [c for c in ablation_conditions(args.preset) if c not in conditions]
        conditions += singles                      # each change alone, on the paper preset
        with_preset += [False] * len(singles)
        if 'async' not in conditions:              # all of them: the preset's Async
            conditions.append('async')
            with_preset.append(True)
    try:
        parsed = [parse_variant(c) for c in conditions]
    except argparse.ArgumentTypeError as exc:
        return _fail(str(exc))
    if args.eval_every < 0:
        return _fail('--eval-every must be >= 0')
    if args.eval_episodes < 0:
        return _fail('--eval-episodes must be >= 0')
    for flag, value in (('--episodes', args.episodes), ('--seeds', args.seeds),
                        ('--workers', args.workers), ('--block', args.block)):
        if value < 1:
            return _fail(f'{flag} must be >= 1 (got {value})')
    if args.first_seed < 0:
        return _fail(f'--first-seed must be >= 0 (got {args.first_seed})')
    if args.address and args.backend != 'ray':
        return _fail('--address needs --backend ray')
    if args.episodes < args.block:
        return _fail(f'--episodes {args.episodes} is shorter than one block (--block '
                     f'{args.block}): give --block {args.episodes} or less')
    if args.arena is not None and not args.arena.is_file():
        return _fail(f'--arena {args.arena}: no such file')
    if out.exists() and not out.is_dir():
        return _fail(f'--out {out}: not a folder')
    try:
        common = _overrides(args.sets, '--set')
        sim_overrides = _overrides(args.sim_sets, '--sim-set')
    except ValueError as exc:
        return _fail(str(exc))
    specs = []
    labels = []
    for label, (name, overrides), preset in zip(conditions, parsed, with_preset):
        base = {}
        if preset and preset_overrides:
            label, base = f'{args.preset}:{label}', preset_overrides
        labels.append(label)
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            specs.append(JobSpec(
                index=len(specs), label=label, condition=name,
                # the preset, then --set, then the condition's own @key=value
                overrides={**base, **common, **overrides}, sim_overrides=sim_overrides,
                seed=seed,
                episodes=args.episodes, eval_episodes=args.eval_episodes,
                arena=str(args.arena) if args.arena else None, run_dir=str(runs_dir),
                block=args.block, train_start=args.train_start, eval_every=args.eval_every,
                preset=args.preset if preset else 'paper'))
    twice = sorted({lb for lb in labels if labels.count(lb) > 1})
    if twice:
        return _fail(f'conditions {", ".join(twice)} appear more than once (with --ablation: '
                     'leave out what it adds)')
    bad = _check_inputs(args, common, sim_overrides)
    if bad:
        return _fail(bad)
    for spec in specs:  # validate every parameter set before starting hours of work
        try:
            spec.validate()
        except (ValueError, OSError) as exc:
            return _fail(f'--conditions {spec.label}: {exc}')
    if args.resume:
        stale = resume_mismatches(specs)
        if stale:
            spec, diffs = stale[0]
            more = f' (and {len(stale) - 1} more runs)' if len(stale) > 1 else ''
            return _fail(
                f'--resume: {spec.result_path()} was made with other settings: '
                f'{"; ".join(diffs)}{more}. Its results are not those of this command: give '
                f'a new --out, or rerun without --resume to redo the runs in {out}')
    runs_dir.mkdir(parents=True, exist_ok=True)
    files.write_text(out / 'experiment.json', json.dumps({
        'argv': sys.argv, 'conditions': conditions, 'labels': labels,
        'episodes': args.episodes,
        'seeds': list(range(args.first_seed, args.first_seed + args.seeds)),
        'eval_episodes': args.eval_episodes, 'sets': common, 'sim_sets': sim_overrides,
        'train_start': args.train_start, 'block': args.block, 'eval_every': args.eval_every,
        'preset': args.preset, 'ablation': args.ablation,
        'overrides': {s.label: s.overrides for s in specs},
        'arena': str(args.arena) if args.arena else None, 'backend': args.backend,
        'address': args.address}, indent=2))
    todo = [s for s in specs if not args.resume or not s.done()]
    t0 = time.monotonic()
    todo = longest_first(todo)
    if todo and args.backend == 'ray':
        try:
            from clis_app.experiments.ray_backend import run_ray
            run_ray(todo, args.workers, args.address,
                    Progress(total_episodes=sum(s.episodes for s in todo), runs=len(todo),
                             quiet=args.quiet, cost=job_costs(todo)))
        except ImportError as exc:
            return _fail(f'--backend ray needs ray ({exc}); `make setup` installs it')
        except ConnectionError as exc:
            return _fail(f'cannot reach the Ray cluster at {args.address}: {exc} (is `ray '
                         'start --head` running there? docs/scale.md)', 1)
    elif todo:
        _run_all(todo, args.workers, args.quiet)
    wall = time.monotonic() - t0
    missing = [s for s in specs if not s.done()]
    if missing:
        return _fail(f'{len(missing)} runs have no results (e.g. {missing[0].label} seed '
                     f'{missing[0].seed}); rerun with --resume', 1)
    results = [JobResult.load(s.result_path()) for s in specs]
    return _finish(out, results, wall if todo else None)


def _finish(out: Path, results: list[JobResult], wall: float | None) -> int:
    """Merge the runs, draw the figures, print the table."""
    from clis_app.experiments import figures
    summary = merge(results, out, wall_seconds=wall)
    figures.draw_all(out, results, summary)
    took = f' in {wall / 60:.1f} min' if wall is not None else ''
    print(f'\nwrote {out}/episodes.csv, eval.csv, summary.json and figures{took}')
    for line in summary['table']:
        print(line)
    for line in divergence_lines(summary):
        print(line)
    return 0


def divergence_lines(summary: dict) -> list[str]:
    """What the divergence guard reported, per condition of a merged ``summary``."""
    from clis_learner.core.guard import DOCS
    gone = {label: c['diverged'] for label, c in summary['conditions'].items()
            if c.get('diverged', {}).get('runs')}
    if not gone:
        return ['divergence guard: no module diverged in any run']
    return [f'WARNING: {label}: a module diverged in {d["runs"]} of {d["of"]} runs ('
            + ', '.join(f'{m} in {n}' for m, n in d['modules'].items()) + f'; {DOCS})'
            for label, d in gone.items()]


def _check_inputs(args: argparse.Namespace, common: dict, sim_overrides: dict) -> str:
    """The first input that is wrong, as a message naming its flag ('' if all are right):
    --set, --sim-set, --arena and --train-start are checked on their own so that the message
    blames the flag, not a condition or a config file."""
    from clis_learner.core.config import check_overrides, load_clis_params
    from cr_sim.core.sim import load_sim_params
    try:
        check_overrides(common, '--set')           # the flag, not clis.yaml, is to blame
    except ValueError as exc:
        return str(exc)
    for flag, load, overrides in (('--set', load_clis_params, common),
                                  ('--sim-set', load_sim_params, sim_overrides)):
        if overrides:
            try:
                load(overrides=overrides)
            except (ValueError, TypeError) as exc:
                return f'{flag}: {exc}'
    try:
        sim_params = load_sim_params(overrides=sim_overrides)
        arena = load_arena(str(args.arena) if args.arena else None, sim_params.robot.radius)
    except (ValueError, OSError) as exc:
        return f'--arena {args.arena or "(config/arena.yaml)"}: {exc}'
    try:
        draw_start(args.train_start, arena, np.random.default_rng(0))
    except ValueError as exc:
        return f'--train-start: {exc}'
    return ''


def resume_mismatches(specs: list[JobSpec]) -> list[tuple[JobSpec, list[str]]]:
    """The finished runs that ``--resume`` would reuse but were made with another spec (other
    episodes, overrides, seeds, arena, preset, parameters...), each with what differs."""
    stale = []
    for spec in specs:
        if not spec.done():
            continue
        try:
            saved = JobResult.load(spec.result_path())
        except (ValueError, TypeError, OSError) as exc:
            stale.append((spec, [f'unreadable ({exc})']))
            continue
        diffs = spec.differences(saved)
        if diffs:
            stale.append((spec, diffs))
    return stale


def figures_only(out: Path) -> int:
    """``--figures-only``: merge and draw the runs that ``OUT/experiment.json`` lists, with
    the settings they were made with (the other flags are not used); writes no
    experiment.json."""
    from clis_app.experiments.runner import result_path
    try:
        exp = json.loads((out / 'experiment.json').read_text())
    except FileNotFoundError:
        return _fail(f'--figures-only: no {out}/experiment.json (not an experiment folder)')
    except ValueError as exc:
        return _fail(f'--figures-only: {out}/experiment.json is damaged ({exc})')
    labels = exp.get('labels') or list(exp['overrides'])
    paths = [result_path(out / 'runs', lb, seed) for lb in labels for seed in exp['seeds']]
    missing = [p for p in paths if not p.is_file()]
    if missing:
        argv = ' '.join(exp.get('argv', [])[1:]) or 'experiment ...'
        return _fail(f'--figures-only: {len(missing)} of {len(paths)} runs of {out} have no '
                     f'results (e.g. {missing[0].name}); to finish them: clis {argv} --resume',
                     1)
    return _finish(out, [JobResult.load(p) for p in paths], None)


def _write_csv(path: Path, rows: list[dict]) -> None:
    if rows:
        files.write_csv(path, rows)


def merge(results: list[JobResult], out: Path, wall_seconds: float | None) -> dict:
    """All runs into episodes.csv / eval.csv and the summary (with the results table)."""
    _write_csv(out / 'episodes.csv', [r for res in results for r in res.table_episodes()])
    _write_csv(out / 'eval.csv', [r for res in results for r in res.evals])
    labels = list(dict.fromkeys(res.spec['label'] for res in results))
    by_label: dict[str, dict] = {}
    block = results[0].block if results else 50
    first, last = f'succ/{block} first', f'succ/{block} last'
    table = [f'{"condition":28s} {"seeds":>5s} {first:>13s} {last:>12s} '
             f'{"eval success":>12s} {"eval time s":>11s}']
    for label in labels:
        runs = [res for res in results if res.spec['label'] == label]
        block = runs[0].block
        curves = np.array([res.success_curve() for res in runs])  # (seeds, blocks)
        evals = [res.evals for res in runs]
        eval_success = np.mean([[e['reached'] for e in ev] for ev in evals])
        eval_time = np.mean([[e['duration'] for e in ev] for ev in evals])
        by_label[label] = {
            'condition': runs[0].spec['condition'], 'overrides': runs[0].spec['overrides'],
            'seeds': [res.spec['seed'] for res in runs], 'block': block,
            'successes_per_block_mean': curves.mean(0).tolist(),
            'successes_per_block_sd': curves.std(0, ddof=1).tolist() if len(runs) > 1 else None,
            'eval_success_rate': float(eval_success), 'eval_mean_time': float(eval_time),
            'eval_points': runs[0].eval_points(),
            'eval_successes_mean': (np.mean([res.eval_success_curve() for res in runs], 0)
                                    .tolist() if runs[0].eval_curve else []),
            'seconds_per_run': float(np.mean([res.seconds for res in runs])),
            'final_diagnostics': _mean_dicts([res.final_diagnostics for res in runs]),
            # the divergence guard (clis_learner.core.guard): runs in which a module diverged
            'diverged': {'runs': sum(bool(res.diverged) for res in runs), 'of': len(runs),
                         'modules': {m: sum(m in res.diverged for res in runs)
                                     for m in runs[0].modules
                                     if any(m in res.diverged for res in runs)}},
        }
        table.append(f'{label:28s} {len(runs):5d} {curves[:, 0].mean():13.1f} '
                     f'{curves[:, -1].mean():12.1f} {eval_success:12.2f} {eval_time:11.1f}')
    summary = {'conditions': by_label, 'wall_seconds': wall_seconds, 'table': table}
    files.write_text(out / 'summary.json', json.dumps(summary, indent=2))
    return summary


def _mean_dicts(dicts: list[dict]) -> dict:
    keys = dict.fromkeys(k for d in dicts for k in d)
    out = {}
    for k in keys:
        values = np.array([d.get(k, np.nan) for d in dicts], float)
        out[k] = float(values[np.isfinite(values)].mean()) if np.isfinite(values).any() else None
    return out
