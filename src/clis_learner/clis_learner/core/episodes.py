"""One row per episode: what the learning curves, the CSVs and the learner's progress report.

The headless runner and the learner node both describe an episode by :func:`episode_row`, from
the episode's :class:`~clis_learner.core.memory.EpisodeMemory`, the arbiter's first draw and the
learner's diagnostics, so a row means the same whichever scheduler produced it.

Columns: ``start``, ``reached`` (0/1), ``duration`` [s], ``collisions`` (steps with a negative
reward), ``ret`` (sum of rewards), ``behaviour`` (the module that acted longest), and per module
``share_M`` (share of the time its command was in force), ``p_M`` and ``v_M`` (``Pr(M | x_0)``
of (3) and ``V_M(x_0)`` at the episode's first draw), the learner's diagnostics
``{key}_M`` for the keys of :data:`ROW_DIAGNOSTICS`, and ``log10c_M``, the log of the
importance product of the whole episode when M never acted in it (NaN otherwise).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
import csv
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from clis_learner.core.memory import EpisodeMemory

__all__ = ['ROW_DIAGNOSTICS', 'acting_shares', 'episode_row', 'keep_rows_until']

#: Per-module diagnostics of the learner copied into each episode row.
ROW_DIAGNOSTICS = ('c_final', 'c_median', 'ess', 'rho_mean', 'delta_abs_mean', 'grad_norm',
                   'n_steps', 'c_max', 'grow_share')


def acting_shares(memory: EpisodeMemory) -> np.ndarray:
    """Share of the episode's commanded time during which each module's command was in force.

    Returns
    -------
    np.ndarray, shape (N,)
        In the order of ``memory.module_names``; sums to 1 (zeros if nothing was commanded).
    """
    t, _, who = memory.actions()
    out = np.zeros(len(memory.module_names))
    if len(t) == 0:
        return out
    ends = np.append(t[1:], memory.t_end)
    np.add.at(out, who, np.maximum(ends - t, 0.0))
    total = out.sum()
    return out / total if total > 0 else out


def episode_row(memory: EpisodeMemory, names: Sequence[str], p_start: np.ndarray | None,
                v_start: np.ndarray | None, diag: Mapping[str, Mapping[str, float]],
                start: str) -> dict[str, Any]:
    """The row of one ended episode (module docstring).

    Parameters
    ----------
    memory : EpisodeMemory
        The ended episode.
    names : sequence of str
        The modules, in the order of ``p_start`` and ``v_start``.
    p_start, v_start : np.ndarray or None, shape (N,)
        Selection probabilities and values of the episode's first draw (NaN if None).
    diag : mapping
        ``Learner.learn`` diagnostics per module (may be empty: learning off).
    start : str
        Where the episode started (a start name, ``'pose'``, ``'wander'`` ...).
    """
    _, r = memory.rewards()
    shares = acting_shares(memory)
    row: dict[str, Any] = {
        'start': start, 'reached': int(memory.reached), 'duration': round(memory.duration, 6),
        'collisions': int(np.count_nonzero(r < 0.0)), 'ret': round(float(np.sum(r)), 6),
        'behaviour': names[int(np.argmax(np.round(shares, 9)))]}   # ties: the first
    nan = np.full(len(names), math.nan)
    p_start = nan if p_start is None else p_start
    v_start = nan if v_start is None else v_start
    for i, name in enumerate(names):
        row[f'share_{name}'] = float(shares[memory.index(name)])
        row[f'p_{name}'] = float(p_start[i])
        row[f'v_{name}'] = float(v_start[i])
        d = diag.get(name)
        if d is None:
            continue
        for key in ROW_DIAGNOSTICS:
            row[f'{key}_{name}'] = float(d[key])
        off_policy = not d['on_policy'] and d['n_steps'] > 0
        row[f'log10c_{name}'] = (math.log10(max(d['c_final'], 1e-300)) if off_policy
                                 else math.nan)
    return row


def keep_rows_until(path: Path, episode: int) -> int:
    """Drop the rows of a run's ``episodes.csv`` after ``episode``: written after the
    checkpoint a run or a restarted learner resumes from (the learner appends an episode's row,
    then checkpoints it), they are learned again. How many were dropped; the file is replaced
    atomically."""
    if not path.is_file():
        return 0
    with open(path, newline='') as fh:
        rows = list(csv.reader(fh))
    if not rows or 'episode' not in rows[0]:
        return 0
    col = rows[0].index('episode')
    keep = [rows[0]] + [r for r in rows[1:] if r and float(r[col]) <= episode]
    if len(keep) == len(rows):
        return 0
    tmp = path.with_suffix('.csv.tmp')
    with open(tmp, 'w', newline='') as fh:
        csv.writer(fh).writerows(keep)
    os.replace(tmp, path)
    return len(rows) - len(keep)
