"""The plan of ``clis study``: its SPEC file read into runs, checked before anything runs.

A SPEC names grids; each grid crosses arenas (files or generated layouts), start protocols,
presets and conditions over seeds (docs/study.md). :func:`plan` expands them into
:class:`Run` s, each with its settings, and checks every value, naming the key and what is
allowed (:class:`SpecError`), and that every Async has its single-module runs to be compared
with.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import hashlib
import json
from pathlib import Path
import re
from typing import Any

from clis_app.study.report import PROTOCOLS, is_single

#: Defaults of the grid keys that have one.
DEFAULTS: dict[str, Any] = {'protocols': ['wander'], 'presets': ['paper'], 'seeds': 5,
                            'episodes': 1000, 'eval_every': 100, 'eval_episodes': 10,
                            'sim_set': {}}
#: Keys of a grid (the top level of a SPEC may give each as a default of its grids).
GRID_KEYS = ('arenas', 'protocols', 'presets', 'conditions', 'seeds', 'episodes',
             'eval_every', 'eval_episodes', 'sim_set')
#: Keys of the top level besides those of a grid.
TOP_KEYS = ('name', 'grids')
_CONDITIONS_ALLOWED = ('innate, view, place, sync, async, or TIMING:MODULE+MODULE... '
                       '(docs/modules.md)')


class SpecError(ValueError):
    """A SPEC value that is not allowed (the message names the key and the allowed values)."""


@dataclass(frozen=True)
class Run:
    """One run of a study: a cell of its grid and a seed, with the settings it is made with."""

    arena: str            # key: a file's stem, or gen-sNNN
    protocol: str
    preset: str           # the preset's name in the study (may carry overrides)
    condition: str
    seed: int
    settings: tuple       # sorted (key, value) pairs, JSON-encoded values

    @property
    def key(self) -> tuple[str, str, str, str, int]:
        return (self.arena, self.protocol, self.preset, self.condition, self.seed)

    def summary_path(self, out: Path) -> Path:
        """``DIR/runs/ARENA/PROTOCOL/PRESET/CONDITION__sSEED.json``."""
        return (out / 'runs' / _slug(self.arena) / self.protocol / _slug(self.preset)
                / f'{_slug(self.condition)}__s{self.seed}.json')

    @property
    def label(self) -> str:
        return f'{self.arena}/{self.protocol}/{self.preset}/{self.condition}'

    def setting(self, name: str) -> Any:
        return json.loads(dict(self.settings)[name])


def _slug(text: str) -> str:
    return re.sub(r'[^A-Za-z0-9_.=+-]+', '_', text)


def _allowed(where: str, value: Any, allowed: str) -> SpecError:
    return SpecError(f'{where}: {value!r} is not allowed; allowed: {allowed}')


def _int(value: Any, where: str, lo: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < lo:
        raise _allowed(where, value, f'an integer >= {lo}')
    return value


def _list(value: Any, where: str, allowed: str) -> list:
    if not isinstance(value, list) or not value:
        raise _allowed(where, value, f'a non-empty list of {allowed}')
    return value


@dataclass(frozen=True)
class _Arena:
    key: str
    text: str
    source: str           # the file as the SPEC names it, or 'clis arena generate --seed K'
    seed: int | None      # the layout seed of a generated arena


@dataclass(frozen=True)
class _Preset:
    name: str
    base: str
    sets: dict
    singles: str | None = None


def _arenas(items: Any, where: str, spec_dir: Path, out: Path, radius: float,
            cache: dict) -> list[_Arena]:
    allowed = ('an arena file (config/arena.yaml format) or {generated: {seeds: [K, ...]}} '
               'or {generated: {first: K, count: N}}')
    out_arenas = []
    for i, item in enumerate(_list(items, where, allowed)):
        w = f'{where}[{i}]'
        if isinstance(item, str):
            out_arenas.append(_file_arena(item, w, spec_dir, out, radius, cache))
            continue
        if not (isinstance(item, Mapping) and set(item) == {'generated'}
                and isinstance(item['generated'], Mapping)):
            raise _allowed(w, item, allowed)
        gen = item['generated']
        if set(gen) == {'seeds'}:
            seeds = [_int(s, f'{w}.generated.seeds[{k}]', 0) for k, s in
                     enumerate(_list(gen['seeds'], f'{w}.generated.seeds', 'layout seeds'))]
        elif set(gen) <= {'first', 'count'} and 'count' in gen:
            first = _int(gen.get('first', 0), f'{w}.generated.first', 0)
            seeds = list(range(first, first + _int(gen['count'], f'{w}.generated.count', 1)))
        else:
            raise _allowed(f'{w}.generated', dict(gen), '{seeds: [K, ...]} or '
                           '{first: K, count: N}')
        for seed in seeds:
            out_arenas.append(_generated_arena(seed, radius, cache))
    return out_arenas


def _generated_arena(seed: int, radius: float, cache: dict) -> _Arena:
    key = f'gen-s{seed:03d}'
    if key not in cache:
        from cr_sim.core.layout import layout_for_seed, layout_yaml
        cache[key] = _Arena(key, layout_yaml(layout_for_seed(seed, radius)),
                            f'clis arena generate --seed {seed}', seed)
    return cache[key]


def _file_arena(name: str, where: str, spec_dir: Path, out: Path, radius: float,
                cache: dict) -> _Arena:
    """An arena file: found from the current folder, else from the SPEC's; else its copy in
    ``DIR/arenas/`` (a study resumed on a machine without the file)."""
    from cr_sim.core.arena import ArenaError, parse_arena
    import yaml
    key = _slug(Path(name).stem)
    if key.startswith('gen-s'):
        raise _allowed(where, name, 'a file whose name does not start with gen-s (the '
                       "generated layouts' names)")
    candidates = [Path(name), spec_dir / name, out / 'arenas' / f'{key}.yaml']
    path = next((p for p in candidates if p.is_file()), None)
    if path is None:
        raise SpecError(f'{where}: {name}: no such file (looked in the current folder and '
                        f'beside the SPEC)')
    text = path.read_text()
    try:
        parse_arena(yaml.safe_load(text), radius, source=name)
    except (ArenaError, yaml.YAMLError) as exc:
        raise SpecError(f'{where}: {exc}') from None
    arena = _Arena(key, text, name, None)
    if key in cache and cache[key].text != text:
        raise SpecError(f'{where}: {name} and {cache[key].source} have the same name {key!r} '
                        'but other layouts: rename one')
    cache[key] = arena
    return arena


def _presets(items: Any, where: str, names: tuple[str, ...]) -> list[_Preset]:
    allowed = (f'a preset ({", ".join(names)}) or {{name: NAME, preset: PRESET, set: '
               '{KEY: VALUE, ...}, singles: OTHER}} (set and singles optional)')
    out = []
    for i, item in enumerate(_list(items, where, allowed)):
        w = f'{where}[{i}]'
        if isinstance(item, str):
            if item not in names:
                raise _allowed(w, item, ', '.join(names))
            out.append(_Preset(item, item, {}))
            continue
        if not isinstance(item, Mapping) or not {'name', 'preset'} <= set(item) \
                or not set(item) <= {'name', 'preset', 'set', 'singles'}:
            raise _allowed(w, item, allowed)
        if item['preset'] not in names:
            raise _allowed(f'{w}.preset', item['preset'], ', '.join(names))
        if not isinstance(item['name'], str) or not re.fullmatch(r'[A-Za-z0-9_.=+-]+',
                                                                 item['name']):
            raise _allowed(f'{w}.name', item['name'], 'a name of letters, digits and _.=+-')
        sets = item.get('set') or {}
        if not isinstance(sets, Mapping):
            raise _allowed(f'{w}.set', sets, 'a mapping KEY: VALUE of config/clis.yaml')
        singles = item.get('singles')
        if singles is not None and (not isinstance(singles, str) or singles == item['name']):
            raise _allowed(f'{w}.singles', singles, "another preset's name in this SPEC")
        out.append(_Preset(item['name'], item['preset'], dict(sets), singles))
    return out


def _conditions(items: Any, where: str) -> list[str]:
    from clis_modules.core.plugin import parse_condition
    out = []
    for i, item in enumerate(_list(items, where, 'conditions')):
        try:
            if not isinstance(item, str) or '@' in item:
                raise ValueError(item)
            parse_condition(item)
        except ValueError:
            raise _allowed(f'{where}[{i}]', item, _CONDITIONS_ALLOWED) from None
        out.append(item)
    return out


def _grid_runs(grid: Mapping[str, Any], where: str, spec_dir: Path, out: Path,
               radius: float, cache: dict, preset_names: tuple[str, ...]) -> list[Run]:
    unknown = sorted(set(grid) - set(GRID_KEYS))
    if unknown:
        raise _allowed(f'{where}{unknown[0]}', grid[unknown[0]],
                       'keys ' + ', '.join(GRID_KEYS))
    g = {**DEFAULTS, **grid}
    for key in ('arenas', 'conditions'):
        if key not in g:
            raise SpecError(f'{where}{key}: missing; allowed keys: {", ".join(GRID_KEYS)}')
    arenas = _arenas(g['arenas'], f'{where}arenas', spec_dir, out, radius, cache)
    protocols = _list(g['protocols'], f'{where}protocols', ', '.join(PROTOCOLS))
    for i, p in enumerate(protocols):
        if p not in PROTOCOLS:
            raise _allowed(f'{where}protocols[{i}]', p, ', '.join(PROTOCOLS))
    presets = _presets(g['presets'], f'{where}presets', preset_names)
    conditions = _conditions(g['conditions'], f'{where}conditions')
    if isinstance(g['seeds'], list):
        seeds = [_int(s, f'{where}seeds[{k}]', 0) for k, s in enumerate(g['seeds'])]
        if not seeds:
            raise _allowed(f'{where}seeds', [], 'a number N (seeds 0..N-1) or a list')
    else:
        seeds = list(range(_int(g['seeds'], f'{where}seeds', 1)))
    episodes = _int(g['episodes'], f'{where}episodes', 1)
    every = _int(g['eval_every'], f'{where}eval_every', 1)
    if episodes % every:
        raise _allowed(f'{where}eval_every', every, f'a divisor of episodes ({episodes}): the '
                       'last evaluation point is the end of learning')
    eval_episodes = _int(g['eval_episodes'], f'{where}eval_episodes', 1)
    if not isinstance(g['sim_set'], Mapping):
        raise _allowed(f'{where}sim_set', g['sim_set'], 'a mapping KEY: VALUE of '
                       'config/sim.yaml')
    for name, items in (('protocols', protocols), ('conditions', conditions),
                        ('seeds', seeds), ('arenas', [a.key for a in arenas]),
                        ('presets', [p.name for p in presets])):
        twice = sorted({str(v) for v in items if items.count(v) > 1})
        if twice:
            raise SpecError(f'{where}{name}: {twice[0]} is listed twice')
    runs = []
    for a in arenas:
        sha = hashlib.sha256(a.text.encode()).hexdigest()[:16]
        for proto in protocols:
            for p in presets:
                for cond in conditions:
                    settings = {'episodes': episodes, 'eval_every': every,
                                'eval_episodes': eval_episodes, 'preset': p.base,
                                'set': p.sets, 'sim_set': dict(g['sim_set']),
                                'arena_sha256': sha, 'layout_seed': a.seed}
                    if p.singles is not None:
                        if is_single(cond):
                            raise _allowed(f'{where}conditions', cond, 'conditions of more '
                                           f'than one module with preset {p.name} (its '
                                           f'single modules are those of {p.singles})')
                        settings['singles'] = p.singles
                    enc = tuple(sorted((k, json.dumps(v, sort_keys=True))
                                       for k, v in settings.items()))
                    runs += [Run(a.key, proto, p.name, cond, s, enc) for s in seeds]
    return runs


def plan(spec: Any, spec_dir: Path, out: Path) -> tuple[list[Run], dict[str, _Arena]]:
    """The runs of a SPEC (its grids' union) and its arenas, every value checked.

    Raises
    ------
    SpecError
        The first value that is not allowed, naming its key and the allowed values.
    """
    from cr_sim.core.robot import load_robot_params

    from clis_app.experiments.experiment import presets as preset_names
    if not isinstance(spec, Mapping):
        raise SpecError(f'the SPEC must be a mapping of keys {", ".join(GRID_KEYS + TOP_KEYS)}')
    unknown = sorted(set(spec) - set(GRID_KEYS + TOP_KEYS))
    if unknown:
        raise _allowed(unknown[0], spec[unknown[0]], 'keys ' + ', '.join(GRID_KEYS + TOP_KEYS))
    if not isinstance(spec.get('name', ''), str):
        raise _allowed('name', spec['name'], 'a string')
    radius = load_robot_params().radius
    cache: dict[str, _Arena] = {}
    names = tuple(preset_names())
    defaults = {k: v for k, v in spec.items() if k in GRID_KEYS}
    if 'grids' in spec:
        grids = _list(spec['grids'], 'grids', 'grids (mappings of ' + ', '.join(GRID_KEYS)
                      + ')')
        runs = []
        for i, grid in enumerate(grids):
            if not isinstance(grid, Mapping):
                raise _allowed(f'grids[{i}]', grid, 'a mapping of ' + ', '.join(GRID_KEYS))
            runs += _grid_runs({**defaults, **grid}, f'grids[{i}].', spec_dir, out, radius,
                               cache, names)
    else:
        runs = _grid_runs(defaults, '', spec_dir, out, radius, cache, names)
    _check_singles(runs)
    unique: dict[tuple, Run] = {}
    for r in runs:
        old = unique.setdefault(r.key, r)
        if old.settings != r.settings:
            raise SpecError(f'run {r.label} seed {r.seed} is in two grids with other '
                            'settings (episodes, evaluation, preset changes): give one of '
                            'them another preset name')
    slugs = {}
    for r in unique.values():
        other = slugs.setdefault(r.summary_path(Path('.')), r)
        if other is not r:
            raise SpecError(f'{r.label} and {other.label} would share a summary file: '
                            'rename one')
    return list(unique.values()), cache


def _check_singles(runs: list[Run]) -> None:
    """Each run of a preset with ``singles: OTHER`` has single-module runs of OTHER on its
    arena, protocol and seed, made with the same episodes, evaluation and simulator."""
    same = ('episodes', 'eval_every', 'eval_episodes', 'sim_set', 'arena_sha256')
    singles = {(r.preset, r.arena, r.protocol, r.seed): r for r in runs
               if is_single(r.condition)}
    for r in runs:
        other = dict(r.settings).get('singles')
        if other is None:
            continue
        q = singles.get((json.loads(other), r.arena, r.protocol, r.seed))
        if q is None:
            raise SpecError(f'presets ({r.preset}).singles: {json.loads(other)} has no '
                            f'single-module run on {r.arena}/{r.protocol} seed {r.seed}: add '
                            'them to the SPEC')
        diff = [k for k in same if r.setting(k) != q.setting(k)]
        if diff:
            raise SpecError(f'presets ({r.preset}).singles: the runs of {q.preset} on '
                            f'{r.arena}/{r.protocol} have another {diff[0]}')


def _check_settings(runs: list[Run], arenas: dict[str, _Arena]) -> None:
    """Load the parameters of every preset, the sim overrides and each condition once, and
    check each arena for the robot of each ``sim_set`` (a bigger body may not fit)."""
    from clis_learner.core.config import check_overrides, load_clis_params, preset_overrides
    from clis_modules.core.modules import condition_periods
    from cr_sim.core.arena import ArenaError, parse_arena
    from cr_sim.core.sim import load_sim_params
    import yaml
    seen, seen_arenas = set(), set()
    for r in runs:
        sets, sim_set = r.setting('set'), r.setting('sim_set')
        key = (r.preset, r.condition, json.dumps(sim_set, sort_keys=True))
        arena_key = (r.arena, key[2])
        if key in seen and arena_key in seen_arenas:
            continue
        seen.add(key)
        seen_arenas.add(arena_key)
        try:
            check_overrides(sets, f'presets ({r.preset}).set')
            params = load_clis_params(overrides={**preset_overrides(r.setting('preset')),
                                                 **sets})
        except (ValueError, TypeError) as exc:
            raise SpecError(f'presets ({r.preset}).set: {exc}') from None
        try:
            radius = load_sim_params(overrides=sim_set).robot.radius
        except (ValueError, TypeError) as exc:
            raise SpecError(f'sim_set: {exc}') from None
        try:
            parse_arena(yaml.safe_load(arenas[r.arena].text), radius,
                        source=arenas[r.arena].source)
        except ArenaError as exc:
            raise SpecError(f'arenas: {exc} (robot radius {radius} m with sim_set '
                            f'{sim_set})') from None
        try:
            condition_periods(params, r.condition)
        except ValueError as exc:
            raise SpecError(f'conditions: {r.condition!r}: {exc}; allowed: '
                            f'{_CONDITIONS_ALLOWED}') from None
