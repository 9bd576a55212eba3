"""``clis study SPEC --out DIR``: a grid of experiments over arenas, start protocols, presets,
conditions and seeds, resumable, with one report.

SPEC is a YAML file (docs/study.md; config/study.yaml, config/study_smoke.yaml)::

    arenas: [config/arena.yaml, config/arena_alt.yaml, {generated: {seeds: [0, 1, 2]}}]
    protocols: [wander, starts, random]      # where learning episodes start (--train-start)
    presets: [improved, {name: improved+b2, preset: improved, set: {common.beta: 2.0}}]
    conditions: [innate, view, place, async]
    seeds: 5                                 # 0..4, or a list
    episodes: 1000
    eval_every: 100                          # the final evaluated success: the last point
    eval_episodes: 10                        # per start A-E at each evaluation point

or ``grids: [{...}, {...}]``, each a grid of those keys (the top level gives their defaults):
the union of the grids is run. A preset with ``singles: OTHER`` (for an option that changes
only how modules are chosen, such as ``arbiter.bonus``) runs no single-module condition: its
report compares it with the single-module runs of preset OTHER on the same arena, protocol
and seed, which the SPEC must have. A generated arena (``{generated: {seeds: [...]}}`` or
``{generated: {first: 0, count: 16}}``) is the layout ``clis arena generate --seed K`` writes.

Every value is checked before anything runs or is written: a bad one is one line naming its
key and the allowed values. Each run is ``run_job`` (clis_app.experiments.runner) on the
experiment's process pool or on Ray (``--backend``); as it finishes, its summary (the
evaluation curve, the final evaluated success, each learned module evaluated alone, the
settings) is written atomically to ``DIR/runs/ARENA/PROTOCOL/PRESET/CONDITION__sSEED.json``
(a few kB: small enough to commit) and its full result file is removed (its checkpoint stays
in ``DIR/work/``). The arenas are copied to ``DIR/arenas/`` and the SPEC to
``DIR/study.yaml``, so ``--resume`` continues an interrupted study, on any machine, from what
is in DIR (it stops if a saved run was made with other settings). The report
(``DIR/report.md``, ``report.json``, ``forest.png``, ``hidden_share.png``, ``layouts.png``)
is drawn from the summaries and the arenas in DIR alone: ``--report-only`` redraws it.
"""

from __future__ import annotations

import argparse
from collections.abc import Mapping
import json
import os
from pathlib import Path
import sys
import time
from typing import Any

from clis_app import files
from clis_app.cli.help import HelpFormatter
from clis_app.study.plan import (
    GRID_KEYS,
    Run,
    SpecError,
    _check_settings,
    plan,
)
from clis_app.study.report import (
    PROTOCOLS,
    SUMMARY_FORMAT,
    _atomic_json,
    _fail,
    report_only,
)

__all__ = ['SpecError', 'Run', 'plan', 'summarise', 'cpu_hours', 'register', 'main',
           'PROTOCOLS', 'GRID_KEYS', 'SUMMARY_FORMAT']


EPILOG = """\
examples:
  clis study config/study_smoke.yaml --out /tmp/smoke          # 48 short runs, < 1 CPU-min
  clis study config/study_smoke.yaml --out /tmp/smoke --plan   # what it would run
  clis study config/study_smoke.yaml --out /tmp/smoke --resume # after a Ctrl-C
  clis study --report-only --out /tmp/smoke                    # redraw the report
  clis study config/study.yaml --out results/study --backend ray --address HEAD:6379

a SPEC (YAML; docs/study.md):
  arenas: [config/arena.yaml, {generated: {seeds: [0, 1, 2]}}]
  protocols: [wander, starts, random]
  presets: [improved, {name: improved+b2, preset: improved, set: {common.beta: 2.0}}]
  conditions: [innate, view, place, async]
  seeds: 5
  episodes: 1000
  eval_every: 100
"""


# ------------------------------------------------------------------------------------------
# the SPEC


# ------------------------------------------------------------------------------------------
# running

def _job_specs(runs: list[Run], out: Path) -> list:
    from clis_learner.core.config import preset_overrides

    from clis_app.experiments.runner import JobSpec
    specs = []
    for k, r in enumerate(runs):
        specs.append(JobSpec(
            index=k, label=r.label, condition=r.condition,
            overrides={**preset_overrides(r.setting('preset')), **r.setting('set')},
            sim_overrides=r.setting('sim_set'), seed=r.seed, episodes=r.setting('episodes'),
            eval_episodes=r.setting('eval_episodes'),
            arena=str((out / 'arenas' / f'{r.arena}.yaml').resolve()),
            run_dir=str(out / 'work'),
            block=r.setting('eval_every'), train_start=r.protocol,
            eval_every=r.setting('eval_every'), preset=r.setting('preset')))
    return specs


def summarise(run: Run, result: Any, hidden: float) -> dict:
    """The summary of a finished run (what the report reads): its settings, the evaluation
    curve, the final evaluated success (the last point), each learned module alone, and the
    modules the divergence guard reported."""
    final = result.eval_curve[-1]
    return {
        'format': SUMMARY_FORMAT, 'arena': run.arena, 'protocol': run.protocol,
        'preset': run.preset, 'condition': run.condition, 'seed': run.seed,
        'settings': {k: json.loads(v) for k, v in run.settings},
        'params_hash': result.params_hash, 'modules': result.modules,
        'hidden_share': hidden,
        'final': {'episode': final['episode'], 'reached': final['reached'], 'n': final['n']},
        'eval_curve': result.eval_curve, 'solo': result.solo,
        # the divergence guard's {module: episode} (clis_learner.core.guard)
        'diverged': dict(getattr(result, 'diverged', {}) or {}),
        'seconds': round(float(result.seconds), 1)}


def _store(run: Run, spec: Any, out: Path, hidden: float) -> None:
    """The summary of ``spec``'s finished result file, written atomically; the result file
    (large: every episode) is removed afterwards, its checkpoint kept."""
    from clis_app.experiments.runner import JobResult
    path = spec.result_path()
    result = JobResult.load(path)
    _atomic_json(run.summary_path(out), summarise(run, result, hidden))
    path.unlink()


def _mismatch(run: Run, saved: Mapping[str, Any], hashes: dict[str, str]) -> str:
    """What makes the saved summary ``saved`` not one of ``run`` ('' when it is): a setting,
    or the parameter hash (config/clis.yaml or a preset file edited since)."""
    now = {k: json.loads(v) for k, v in run.settings}
    old = saved.get('settings', {})
    diffs = [f'{k}={old.get(k)!r} (now {now[k]!r})' for k in now if old.get(k) != now[k]]
    want = _params_hash(run, hashes)
    if not diffs and saved.get('params_hash') != want:
        diffs.append(f'parameters (hash {saved.get("params_hash")}, now {want}: config/clis.yaml '
                     'or a preset file changed)')
    return '; '.join(diffs)


def _params_hash(run: Run, cache: dict[str, str]) -> str:
    """The hash of ``run``'s learning parameters (config/clis.yaml, its preset, its set)."""
    from clis_learner.core.config import load_clis_params, params_hash, preset_overrides
    key = json.dumps([run.setting('preset'), run.setting('set')], sort_keys=True)
    if key not in cache:
        cache[key] = params_hash(load_clis_params(overrides={
            **preset_overrides(run.setting('preset')), **run.setting('set')}))
    return cache[key]


def _make_progress(todo_runs: list[Run], specs: list, out: Path, hidden: dict[str, float],
                   quiet: bool) -> Any:
    from clis_app.experiments.pool import Progress

    class StudyProgress(Progress):
        """The experiment's progress line; each finished run's summary is written first."""

        def finish(self, job: int, episodes: int, note: str) -> None:
            run = todo_runs[job]
            _store(run, specs[job], out, hidden[run.arena])
            super().finish(job, episodes, f'{run.label} s{run.seed} done')

    from clis_app.experiments.pool import job_costs
    return StudyProgress(total_episodes=sum(s.episodes for s in specs), runs=len(specs),
                         quiet=quiet, cost=job_costs(specs))


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser('study', help='run a grid of experiments (arenas x protocols x presets '
                       'x conditions x seeds) and report it', description=__doc__,
                       epilog=EPILOG, formatter_class=HelpFormatter)
    p.add_argument('spec', type=Path, nargs='?', metavar='SPEC',
                   help='the study (YAML; docs/study.md); with --resume the default is '
                        'DIR/study.yaml (--report-only reads none)')
    p.add_argument('--out', type=Path, required=True, metavar='DIR', help='output folder')
    p.add_argument('--resume', action='store_true',
                   help='continue a study in DIR: keep its finished runs (stops if any was '
                        'made with other settings)')
    p.add_argument('--report-only', action='store_true',
                   help="only redraw DIR's report from its run summaries")
    p.add_argument('--plan', action='store_true',
                   help='print the runs the SPEC makes (and which are done in DIR); run none')
    p.add_argument('--workers', type=int, default=os.cpu_count() or 1,
                   help='parallel processes (with --backend ray and no --address: the CPUs '
                        'of the local Ray instance)')
    p.add_argument('--backend', choices=('process', 'ray'), default='process',
                   help="'process': a pool on this machine; 'ray': Ray tasks (docs/scale.md)")
    p.add_argument('--address', metavar='ADDR',
                   help='with --backend ray: the Ray cluster to join (host:port)')
    p.add_argument('--quiet', action='store_true', help='no progress line')
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    """``clis study``: the whole SPEC is checked before anything is written to DIR."""
    import yaml
    out: Path = args.out
    if out.exists() and not out.is_dir():
        return _fail(f'--out {out}: not a folder')
    if args.report_only:
        return report_only(out)
    spec_path = args.spec
    if spec_path is None:
        if not args.resume:
            return _fail('give a SPEC (a YAML file; docs/study.md)')
        spec_path = out / 'study.yaml'
    if not spec_path.is_file():
        return _fail(f'SPEC {spec_path}: no such file')
    if args.workers < 1:
        return _fail(f'--workers must be >= 1 (got {args.workers})')
    if args.address and args.backend != 'ray':
        return _fail('--address needs --backend ray')
    spec_text = spec_path.read_text()
    try:
        spec = yaml.safe_load(spec_text)
        runs, arenas = plan(spec, spec_path.parent, out)
        _check_settings(runs, arenas)
    except yaml.YAMLError as exc:
        return _fail(f'SPEC {spec_path}: not YAML ({exc})')
    except SpecError as exc:
        return _fail(f'SPEC {spec_path}: {exc}')
    done = [r for r in runs if r.summary_path(out).is_file()]
    if args.plan:
        return _print_plan(runs, done, out)
    if done and not args.resume:
        return _fail(f'{out} holds {len(done)} finished runs of this study: --resume to '
                     'continue it, or give another --out')
    hashes: dict[str, str] = {}
    for r in done:
        try:
            saved = json.loads(r.summary_path(out).read_text())
        except (OSError, ValueError) as exc:
            return _fail(f'--resume: {r.summary_path(out)} is unreadable ({exc}): remove it '
                         'to run it again')
        diff = _mismatch(r, saved, hashes)
        if diff:
            return _fail(f'--resume: {r.summary_path(out)} was made with other settings: '
                         f'{diff}. Give another --out, or remove it to run it again')
    for key, a in arenas.items():
        copy = out / 'arenas' / f'{key}.yaml'
        if copy.is_file() and copy.read_text() != a.text:
            return _fail(f'arenas: {a.source} differs from {copy}, the layout of the runs '
                         'saved in DIR: give another --out (or restore the file)')
    # everything checked: write
    from cr_sim.core.arena import parse_arena
    from cr_sim.core.layout import hidden_share
    from cr_sim.core.robot import load_robot_params
    radius = load_robot_params().radius
    (out / 'arenas').mkdir(parents=True, exist_ok=True)
    (out / 'work').mkdir(exist_ok=True)
    if spec_path.resolve() != (out / 'study.yaml').resolve():
        files.write_text(out / 'study.yaml', spec_text)
    hidden = {}
    for key, a in arenas.items():
        copy = out / 'arenas' / f'{key}.yaml'
        if not copy.is_file():
            files.write_text(copy, a.text)
        hidden[key] = hidden_share(parse_arena(yaml.safe_load(a.text), radius), radius)
    _atomic_json(out / 'plan.json', {'name': spec.get('name'),
                                      'runs': [list(r.key) for r in runs]})
    done_keys = {r.key for r in done}
    todo = [r for r in runs if r.key not in done_keys]
    specs = _job_specs(todo, out)
    # a run whose result file was written but not summarised (interrupted in between)
    left = []
    for r, s in zip(todo, specs):
        if s.done():
            from clis_app.experiments.runner import JobResult
            if not s.differences(JobResult.load(s.result_path())):
                _store(r, s, out, hidden[r.arena])
                continue
        left.append((r, s))
    from clis_app.experiments.pool import longest_first
    order = {id(s): k for k, (_, s) in enumerate(left)}
    ordered = longest_first([s for _, s in left])
    todo_runs = [left[order[id(s)]][0] for s in ordered]
    print(f'clis study: {len(runs)} runs ({len(runs) - len(left)} done, {len(left)} to run, '
          f'roughly {_cpu_text(cpu_hours([r for r, _ in left]))}) in {out}',
          file=sys.stderr)
    t0 = time.monotonic()
    if ordered:
        for k, s in enumerate(ordered):
            s.index = k
        progress = _make_progress(todo_runs, ordered, out, hidden, args.quiet)
        if args.backend == 'ray':
            try:
                from clis_app.experiments.ray_backend import run_ray
                run_ray(ordered, args.workers, args.address, progress)
            except ImportError as exc:
                return _fail(f'--backend ray needs ray ({exc}); `make setup` installs it')
            except ConnectionError as exc:
                return _fail(f'cannot reach the Ray cluster at {args.address}: {exc}', 1)
        else:
            from clis_app.experiments.pool import _run_all
            _run_all(ordered, args.workers, args.quiet, progress)
        if not args.quiet:
            print(file=sys.stderr)
    missing = [r for r in runs if not r.summary_path(out).is_file()]
    if missing:
        return _fail(f'{len(missing)} runs have no summary (e.g. {missing[0].label} seed '
                     f'{missing[0].seed}); rerun with --resume', 1)
    took = time.monotonic() - t0
    code = report_only(out)
    if ordered:
        print(f'clis study: {len(ordered)} runs in {took / 60:.1f} min', file=sys.stderr)
    return code


#: CPU seconds of 1000 learning episodes of Innate alone (docs/benchmarks.md: 7 CPU-s); the
#: other conditions cost :data:`clis_app.experiments.pool._COST` times that.
_INNATE_CPU_S = 7.0


def cpu_hours(runs: list[Run]) -> float:
    """A rough estimate of the CPU time of ``runs`` [h]: the benchmarks' cost per learning
    episode of each condition, an evaluation episode counted as a learning one."""
    from clis_app.experiments.pool import _cost
    total = 0.0
    for r in runs:
        episodes, every = r.setting('episodes'), r.setting('eval_every')
        evals = 5 * r.setting('eval_episodes') * (episodes // every + 2)
        total += _INNATE_CPU_S * _cost(r.condition) * (episodes + evals) / 1000
    return total / 3600


def _cpu_text(hours: float) -> str:
    return f'{hours:.1f} CPU-hours' if hours >= 1 else f'{60 * hours:.1f} CPU-minutes'


def _print_plan(runs: list[Run], done: list[Run], out: Path) -> int:
    from collections import Counter
    cells = Counter((r.preset, r.protocol) for r in runs)
    arenas = sorted({r.arena for r in runs})
    print(f'{len(runs)} runs ({len(done)} done in {out}), roughly '
          f'{_cpu_text(cpu_hours(runs))}; {len(arenas)} arenas: ' + ', '.join(arenas))
    for (preset, proto), n in sorted(cells.items()):
        conds = sorted({r.condition for r in runs if (r.preset, r.protocol) == (preset, proto)})
        print(f'  preset {preset}, protocol {proto}: {n} runs; conditions {", ".join(conds)}')
    return 0
