"""An experiment's unit of work: a run's specification (:class:`JobSpec`, what a worker or a Ray
task is given) and its results (:class:`JobResult`, saved atomically to ``OUT/runs/`` as soon as
the run ends, and compared with a new spec on ``--resume``). The headless runner
(:mod:`clis_app.experiments.runner`) turns the one into the other
(:func:`~clis_app.experiments.runner.run_job`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field
import json
import os
from pathlib import Path
import re

from clis_learner.core.config import ClisParams, load_clis_params, params_hash
from clis_modules.core.modules import condition_periods
from clis_modules.core.plugin import parse_condition
from cr_sim.core.arena import Arena, load_arena
from cr_sim.core.sim import SimParams, load_sim_params
from cr_sim.core.starts import draw_start
import numpy as np

from clis_app import files

__all__ = ['JobSpec', 'JobResult', 'arena_dict', 'result_path']


def arena_dict(arena: Arena) -> dict:
    """What the figures need of the arena (plain JSON)."""
    def boxes(items):
        return [[*b.lo, *b.hi] for b in items]
    d = arena.destination
    return {'bounds': list(arena.bounds), 'short': boxes(arena.short_obstacles),
            'tall': boxes(arena.tall_obstacles),
            'landmarks': [[lm.x, lm.y] for lm in arena.landmarks],
            'destination': [d.x, d.y, d.goal_radius],
            'starts': {s.name: [s.x, s.y] for s in arena.starts}}


def result_path(run_dir: str | os.PathLike, label: str, seed: int) -> Path:
    """Where the run of ``label`` (a condition with its overrides) and ``seed`` is saved."""
    slug = re.sub(r'[^A-Za-z0-9_.=-]+', '_', label)
    return Path(run_dir) / f'{slug}__s{seed}.json'


@dataclass
class JobSpec:
    """One run: a condition (with overrides) and a seed."""

    index: int
    label: str
    condition: str
    overrides: dict
    sim_overrides: dict
    seed: int
    episodes: int
    eval_episodes: int
    arena: str | None
    run_dir: str
    block: int = 50
    train_start: str = 'wander'
    eval_every: int = 0
    preset: str = 'paper'

    def load(self) -> tuple[ClisParams, SimParams, Arena]:
        """The parameters of this run (validated: a bad override raises naming the key)."""
        params = load_clis_params(overrides=self.overrides)
        sim_params = load_sim_params(overrides=self.sim_overrides)
        arena = load_arena(self.arena, sim_params.robot.radius)
        return params, sim_params, arena

    def validate(self) -> None:
        parse_condition(self.condition)                   # raises if not a condition
        params, _, arena = self.load()
        condition_periods(params, self.condition)         # raises naming an unknown module
        draw_start(self.train_start, arena, np.random.default_rng(0))  # raises if unknown

    def result_path(self) -> Path:
        return result_path(self.run_dir, self.label, self.seed)

    def done(self) -> bool:
        return self.result_path().is_file()

    def differences(self, saved: JobResult) -> list[str]:
        """What makes the saved run ``saved`` (at this spec's path) not a run of this spec:
        ``'key=SAVED (now NEW)'`` for each field of the spec that changes results (all but
        ``index`` and ``run_dir``), the parameter hash (config/clis.yaml with the overrides,
        so also an edited config file) and the arena; empty when it is this run."""
        try:
            old = asdict(JobSpec(**{**saved.spec, 'index': self.index,
                                    'run_dir': self.run_dir}))
        except TypeError as exc:                       # a spec of another format
            return [f'spec format ({exc})']
        new = asdict(self)
        diffs = [f'{k}={old[k]!r} (now {new[k]!r})' for k in new if old[k] != new[k]]
        if diffs:
            return diffs
        params, _, arena = self.load()
        if saved.params_hash and saved.params_hash != params_hash(params):
            diffs.append(f'parameters (hash {saved.params_hash}, now {params_hash(params)}: '
                         'config/clis.yaml changed)')
        if saved.arena and saved.arena != json.loads(json.dumps(arena_dict(arena))):
            diffs.append('arena (its file changed)')
        return diffs


@dataclass
class JobResult:
    """Everything a run produced (saved as one JSON file)."""

    spec: dict
    modules: list[str]
    block: int
    episodes: list[dict]
    evals: list[dict]
    place_map: dict | None
    arena: dict
    seconds: float
    final_diagnostics: dict = field(default_factory=dict)
    params_hash: str = ''
    eval_curve: list[dict] = field(default_factory=list)
    solo: dict = field(default_factory=dict)
    #: ``{module: learned episode (from 1)}`` at which the divergence guard reported the
    #: module (:mod:`clis_learner.core.guard`); empty when none diverged
    diverged: dict = field(default_factory=dict)

    def table_episodes(self) -> list[dict]:
        """The learning episodes as ``episodes.csv`` shows them: numbered from 1, the n-th
        learning episode n, as ``clis run``'s ``episodes.csv``, the bags' episode events and
        the checkpoints count them (docs/design.md §6). :attr:`episodes` keeps the index from
        0 that the saved runs (and the golden digest of test_coop) have always had."""
        return [{**row, 'episode': int(row['episode']) + 1} for row in self.episodes]

    def eval_success_curve(self) -> list[float]:
        """Successes out of ``n`` evaluation episodes (A-E, learning off) at each evaluation
        point (after 0, ``eval_every``, ... learning episodes); empty without periodic
        evaluation."""
        return [float(p['reached']) for p in self.eval_curve]

    def eval_points(self) -> list[int]:
        """Learning episodes done at each evaluation point."""
        return [int(p['episode']) for p in self.eval_curve]

    def _blocks(self, key: str) -> np.ndarray:
        values = np.array([row.get(key, np.nan) for row in self.episodes], float)
        n_blocks = len(values) // self.block
        return values[:n_blocks * self.block].reshape(n_blocks, self.block)

    def success_curve(self) -> list[float]:
        """Successes per block of ``block`` learning episodes."""
        return self._blocks('reached').sum(1).tolist()

    def selection_shares(self) -> np.ndarray:
        """Mean share of the episode time each module acted, per block, shape (B, N)."""
        return np.stack([self._blocks(f'share_{m}').mean(1) for m in self.modules], axis=1)

    def block_stat(self, key: str, fn: Callable = np.nanmean) -> np.ndarray:
        """``fn`` of column ``key`` over each block (NaN where a block has no value)."""
        blocks = self._blocks(key)
        out = np.full(len(blocks), np.nan)
        for k, row in enumerate(blocks):
            finite = row[np.isfinite(row)]
            if finite.size:
                out[k] = fn(finite)
        return out

    def save(self) -> Path:
        """Write to the spec's result path, atomically (a crash never leaves half a file)."""
        path = JobSpec(**self.spec).result_path()
        files.write_text(path, json.dumps(asdict(self), allow_nan=True))
        return path

    @classmethod
    def load(cls, path: str | os.PathLike) -> JobResult:
        return cls(**json.loads(Path(path).read_text()))
