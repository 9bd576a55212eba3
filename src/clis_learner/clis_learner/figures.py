"""Figures of the experiments (the paper's Fig. 3-5, plus the diagnostics that explain them).

Every figure is drawn from saved runs (:class:`clis_learner.core.runner.JobResult`), so
``clis experiment --figures-only`` redraws them without rerunning anything.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from scipy import stats  # noqa: E402

MODULE_COLOURS = {'innate': 'black', 'view': 'magenta', 'place': 'green'}
STARTS = ('A', 'B', 'C', 'D', 'E')


def band(curves: np.ndarray, level: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
    """Mean and half-width of the ``level`` t-interval over axis 0 (seeds).

    Parameters
    ----------
    curves : np.ndarray, shape (n_seeds, n_points)
    """
    mean = curves.mean(0)
    n = curves.shape[0]
    if n < 2:
        return mean, np.zeros_like(mean)
    half = stats.t.ppf(0.5 + level / 2, n - 1) * curves.std(0, ddof=1) / np.sqrt(n)
    return mean, half


def _labels(results) -> list[str]:
    return list(dict.fromkeys(r.spec['label'] for r in results))


def _runs(results, label):
    return [r for r in results if r.spec['label'] == label]


def _multi_module_labels(results) -> list[str]:
    """Labels of the conditions with more than one module (Sync, Async and their variants)."""
    return [lb for lb in _labels(results) if len(_runs(results, lb)[0].modules) > 1]


def _save(fig, path: Path) -> None:
    fig.tight_layout()
    fig.savefig(path, dpi=120, bbox_inches='tight')
    plt.close(fig)


def _curves(results, path: Path, curve, xlabel: str, ylabel: str, ymax: float,
            title: str) -> None:
    """One line per condition with its 95% band over seeds; ``curve(runs) -> (x, curves)``
    with ``curves`` of shape (n_seeds, n_points)."""
    labels = _labels(results)
    fig, ax = plt.subplots(figsize=(8, 4.2))
    for label in labels:
        runs = _runs(results, label)
        x, curves = curve(runs)
        mean, half = band(curves)
        line, = ax.plot(x, mean, label=f'{label} (n={len(runs)})')
        ax.fill_between(x, mean - half, mean + half, color=line.get_color(), alpha=0.15)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_ylim(0, ymax)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc='upper center', bbox_to_anchor=(0.5, -0.2),
              ncol=2 if len(labels) > 5 else len(labels))
    ax.set_title(title)
    _save(fig, path)


def fig3a(results, path: Path) -> None:
    """Fig. 3a as the paper reads it (its Fig. 2 caption): successes out of the evaluation
    episodes from A-E (learning off) at every evaluation point, mean and 95% band over seeds.
    Runs without periodic evaluation: the learning-episode curve (:func:`fig3a_learning`)."""
    if not all(_runs(results, lb)[0].eval_curve for lb in _labels(results)):
        fig3a_learning(results, path)
        return

    def curve(runs):
        n_points = min(len(r.eval_curve) for r in runs)
        return (np.array(runs[0].eval_points()[:n_points]),
                np.array([r.eval_success_curve()[:n_points] for r in runs], float))

    n_eval = int(results[0].eval_curve[0]['n'])
    _curves(results, path, curve, 'learning episodes',
            f'successes in {n_eval} evaluation episodes (A-E)', n_eval,
            'Fig. 3a: evaluation from A-E, learning off (mean, 95% t-band over seeds)')


def fig3a_learning(results, path: Path) -> None:
    """Successes per block of learning episodes, mean and 95% band over seeds."""
    block = results[0].block

    def curve(runs):
        curves = np.array([r.success_curve() for r in runs], float)
        return (np.arange(curves.shape[1]) + 1) * block, curves

    _curves(results, path, curve, 'episodes', f'successes per {block} episodes', block,
            'successes of the learning episodes (mean, 95% t-band over seeds)')


def fig3bc(results, path: Path) -> None:
    """Share of episodes in which each module was selected, per block, per multi-module run."""
    labels = _multi_module_labels(results)
    if not labels:
        return
    fig, axes = plt.subplots(len(labels), 1, figsize=(7, 2.4 * len(labels)), squeeze=False)
    for ax, label in zip(axes[:, 0], labels):
        runs = _runs(results, label)
        shares = np.mean([r.selection_shares() for r in runs], axis=0)  # (blocks, modules)
        x = (np.arange(shares.shape[0]) + 1) * runs[0].block
        bottom = np.zeros(shares.shape[0])
        for k, name in enumerate(runs[0].modules):
            ax.bar(x, shares[:, k], bottom=bottom, width=runs[0].block * 0.9,
                   color=MODULE_COLOURS.get(name), label=name)
            bottom += shares[:, k]
        ax.set_ylim(0, 1)
        ax.set_ylabel('selection share')
        ax.set_title(f'{label}: module acting (mean over {len(runs)} seeds)', fontsize=9)
        ax.legend(fontsize=7, loc='upper right', ncol=3)
    axes[-1, 0].set_xlabel('episodes')
    fig.suptitle('Fig. 3b/c: selection ratio over learning', fontsize=10)
    _save(fig, path)


def floor_bounds(arena: dict) -> tuple[float, float, float, float]:
    """``(xmin, ymin, xmax, ymax)`` of an arena dict (results saved before ``bounds`` have
    the half side of the square, ``half_size``)."""
    if 'bounds' in arena:
        return tuple(arena['bounds'])
    h = arena['half_size']
    return (-h, -h, h, h)


def draw_arena(ax, arena: dict) -> None:
    """Obstacles (short: green, tall: dark), landmarks, destination and starts."""
    fx0, fy0, fx1, fy1 = floor_bounds(arena)
    ax.add_patch(plt.Rectangle((fx0, fy0), fx1 - fx0, fy1 - fy0, fill=False, lw=2))
    for key, colour in (('short', 'tab:green'), ('tall', 'dimgray')):
        for x0, y0, x1, y1 in arena[key]:
            ax.add_patch(plt.Rectangle((x0, y0), x1 - x0, y1 - y0, color=colour, alpha=0.9))
    for x, y in arena['landmarks']:
        ax.plot(x, y, 'o', color='orange', ms=7, mec='k')
    dx, dy, r = arena['destination']
    ax.add_patch(plt.Circle((dx, dy), r, color='red', alpha=0.6))
    for name, (x, y) in arena['starts'].items():
        ax.plot(x, y, 'x', color='blue')
        ax.annotate(name, (x, y), xytext=(3, 3), textcoords='offset points', color='blue')
    ax.set_xlim(fx0, fx1)
    ax.set_ylim(fy0, fy1)
    ax.set_aspect('equal')


def fig4(results, path: Path) -> None:
    """Map of Pr(M_pl | x) at the end of learning, robot heading to the destination."""
    labels = [lb for lb in _labels(results) if _runs(results, lb)[0].place_map is not None]
    if not labels:
        return
    fig, axes = plt.subplots(1, len(labels), figsize=(4.2 * len(labels), 4), squeeze=False)
    for ax, label in zip(axes[0], labels):
        runs = _runs(results, label)
        pm = runs[0].place_map
        maps = np.array([r.place_map['p'] for r in runs], float)  # (seeds, ny, nx)
        p = np.full(maps.shape[1:], np.nan)
        free = np.isfinite(maps).all(0)
        p[free] = maps[:, free].mean(0)
        xs, ys = np.asarray(pm['x'], float), np.asarray(pm['y'], float)
        d = xs[1] - xs[0] if len(xs) > 1 else 0.1              # the map's resolution
        im = ax.imshow(p, origin='lower', vmin=0, vmax=1,
                       extent=(xs[0] - d / 2, xs[-1] + d / 2, ys[0] - d / 2, ys[-1] + d / 2),
                       cmap='viridis', interpolation='nearest')
        draw_arena(ax, runs[0].arena)
        ax.set_title(f'{label}: Pr(M_pl | x)\n(mean of {len(runs)} seeds; '
                     f'grid {len(pm["x"])}x{len(pm["y"])})', fontsize=9)
        fig.colorbar(im, ax=ax, fraction=0.046)
    fig.suptitle('Fig. 4: probability of selecting the place module at the end of learning',
                 fontsize=10)
    _save(fig, path)


def _mean_map(maps: np.ndarray) -> np.ndarray:
    """Mean over seeds (axis 0) where every seed has a value; NaN elsewhere."""
    p = np.full(maps.shape[1:], np.nan)
    free = np.isfinite(maps).all(0)
    p[free] = maps[:, free].mean(0)
    return p


def fig4_modules(results, path: Path) -> None:
    """Where each module is chosen at the end of learning: Pr(i | x) of the selection rule for
    every module (rows: multi-module conditions), robot heading to the destination."""
    labels = [lb for lb in _labels(results) if (_runs(results, lb)[0].place_map or {})
              .get('modules')]
    if not labels:
        return
    names = list(_runs(results, labels[0])[0].place_map['modules'])
    fig, axes = plt.subplots(len(labels), len(names), figsize=(3.6 * len(names),
                             3.4 * len(labels)), squeeze=False)
    for row, label in enumerate(labels):
        runs = _runs(results, label)
        pm = runs[0].place_map
        xs, ys = np.asarray(pm['x'], float), np.asarray(pm['y'], float)
        d = xs[1] - xs[0] if len(xs) > 1 else 0.1
        for col, name in enumerate(names):
            ax = axes[row, col]
            p = _mean_map(np.array([r.place_map['modules'][name] for r in runs], float))
            im = ax.imshow(p, origin='lower', vmin=0, vmax=1, cmap='viridis',
                           extent=(xs[0] - d / 2, xs[-1] + d / 2, ys[0] - d / 2, ys[-1] + d / 2),
                           interpolation='nearest')
            draw_arena(ax, runs[0].arena)
            ax.set_title(f'{label}: Pr({name} | x) ({len(runs)} seeds)', fontsize=8)
        fig.colorbar(im, ax=axes[row, -1], fraction=0.046)
    fig.suptitle('Fig. 4 for every module: probability of being selected at the end of '
                 'learning', fontsize=10)
    _save(fig, path)


def fig5(results, path: Path) -> None:
    """Mean time to the destination from each start (evaluation episodes), per condition."""
    labels = _labels(results)
    fig, ax = plt.subplots(figsize=(7, 4))
    width = 0.8 / max(len(labels), 1)
    for k, label in enumerate(labels):
        runs = _runs(results, label)
        per_seed = np.array([[np.mean([e['duration'] for e in r.evals if e['start'] == s])
                              for s in STARTS] for r in runs])
        mean, half = band(per_seed)
        ax.bar(np.arange(len(STARTS)) + k * width, mean, width, yerr=half, capsize=2,
               label=label)
    ax.set_xticks(np.arange(len(STARTS)) + width * (len(labels) - 1) / 2)
    ax.set_xticklabels(STARTS)
    ax.set_xlabel('start point')
    ax.set_ylabel('time to destination [s] (timeout = 60)')
    ax.legend(fontsize=8)
    ax.grid(axis='y', alpha=0.3)
    ax.set_title('Fig. 5: time to the destination after learning (95% t-band over seeds)')
    _save(fig, path)


def fig_diagnostics(results, path: Path) -> None:
    """Why cooperation does or does not happen: selection probability and IS products."""
    labels = _multi_module_labels(results)
    if not labels:
        return
    fig, axes = plt.subplots(2, len(labels), figsize=(4.5 * len(labels), 6), squeeze=False)
    for col, label in enumerate(labels):
        runs = _runs(results, label)
        modules = runs[0].modules
        block = runs[0].block
        for name in modules:
            p = np.mean([r.block_stat(f'p_{name}', np.mean) for r in runs], axis=0)
            x = (np.arange(len(p)) + 1) * block
            axes[0, col].plot(x, p, color=MODULE_COLOURS.get(name), label=name)
            c = np.mean([r.block_stat(f'log10c_{name}', np.median) for r in runs], axis=0)
            axes[1, col].plot(x, c, color=MODULE_COLOURS.get(name), label=name)
        axes[0, col].set_ylim(0, 1)
        axes[0, col].set_title(f'{label}: Pr(i | x(0)) (eq. 3)', fontsize=9)
        axes[1, col].set_title(f'{label}: median log10 c at episode end\n'
                               '(off-policy episodes; eq. 6-7; floored at -300)', fontsize=9)
        axes[1, col].set_xlabel('episodes')
        for ax in axes[:, col]:
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7)
    _save(fig, path)


def draw_all(out: Path, results, summary: dict) -> list[Path]:
    """Draw every figure into ``out``; return the files written."""
    paths = []
    for name, fn in (('fig3a.png', fig3a), ('fig3a_learning.png', fig3a_learning),
                     ('fig3bc.png', fig3bc), ('fig4.png', fig4),
                     ('fig4_modules.png', fig4_modules),
                     ('fig5.png', fig5), ('diagnostics.png', fig_diagnostics)):
        fn(results, out / name)
        if (out / name).exists():
            paths.append(out / name)
    return paths
