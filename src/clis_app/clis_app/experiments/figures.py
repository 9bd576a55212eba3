"""Figures of the experiments (the paper's Fig. 3-5, plus the diagnostics that explain them).

Every figure is drawn from saved runs (:class:`clis_app.experiments.runner.JobResult`), so
``clis experiment --figures-only`` redraws them without rerunning anything.
"""

from __future__ import annotations

from collections.abc import Iterator
import contextlib
from pathlib import Path
import signal
import threading

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from scipy import stats  # noqa: E402

from clis_app import files  # noqa: E402

MODULE_COLOURS = {'innate': 'black', 'view': 'magenta', 'place': 'green', 'wall': 'tab:orange'}
STARTS = ('A', 'B', 'C', 'D', 'E')


#: Fewest seeds for a confidence band: with 2 the t-interval has 1 degree of freedom
#: (t = 12.7) and spans more than the axis, which says nothing.
MIN_BAND_SEEDS = 3


def band(curves: np.ndarray, level: float = 0.95,
         min_n: int = MIN_BAND_SEEDS) -> tuple[np.ndarray, np.ndarray]:
    """Mean and half-width of the ``level`` t-interval over axis 0 (seeds).

    Parameters
    ----------
    curves : np.ndarray, shape (n_seeds, n_points)
    level : float
        Confidence level of the interval.
    min_n : int
        Fewest seeds for an interval; with fewer the half-width is NaN (no band: draw or
        print the seeds themselves and say so).

    Returns
    -------
    mean, half : np.ndarray, shape (n_points,)
    """
    curves = np.asarray(curves, float)
    mean = curves.mean(0)
    n = curves.shape[0]
    if n < max(min_n, 2):
        return mean, np.full_like(mean, np.nan)
    half = stats.t.ppf(0.5 + level / 2, n - 1) * curves.std(0, ddof=1) / np.sqrt(n)
    return mean, half


def band_note(n: int) -> str:
    """What a figure or table says about its band for ``n`` seeds."""
    if n >= MIN_BAND_SEEDS:
        return f'mean, 95% t-band over n={n} seeds'
    return f'n={n} seed{"s" if n > 1 else ""}: no band (fewer than {MIN_BAND_SEEDS} seeds)'


def _labels(results) -> list[str]:
    return list(dict.fromkeys(r.spec['label'] for r in results))


def _runs(results, label):
    return [r for r in results if r.spec['label'] == label]


def _multi_module_labels(results) -> list[str]:
    """Labels of the conditions with more than one module (Sync, Async and their variants)."""
    return [lb for lb in _labels(results) if len(_runs(results, lb)[0].modules) > 1]


def _save(fig, path: Path) -> None:
    """Save and close ``fig``; written to a temporary file and renamed, so an interrupted
    drawing never leaves half a PNG."""
    path = Path(path)
    fig.tight_layout()
    with files.atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120, bbox_inches='tight', format=path.suffix.lstrip('.') or 'png')
    plt.close(fig)


def _curves(results, path: Path, curve, xlabel: str, ylabel: str, ymax: float,
            title: str) -> None:
    """One line per condition (with markers, so that a single point shows) and its 95% band
    over seeds; with fewer than :data:`MIN_BAND_SEEDS` seeds no band but every seed drawn
    thin. ``curve(runs) -> (x, curves)`` with ``curves`` of shape (n_seeds, n_points)."""
    labels = _labels(results)
    fig, ax = plt.subplots(figsize=(8, 4.2))
    ns = set()
    for label in labels:
        runs = _runs(results, label)
        x, curves = curve(runs)
        mean, half = band(curves)
        ns.add(len(runs))
        line, = ax.plot(x, mean, marker='o', ms=3 if len(x) > 30 else 5,
                        label=f'{label} (n={len(runs)})')
        if np.isfinite(half).all():
            ax.fill_between(x, mean - half, mean + half, color=line.get_color(), alpha=0.15)
        elif len(runs) > 1:
            for c in curves:
                ax.plot(x, c, color=line.get_color(), lw=0.7, alpha=0.5, ls='--')
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_ylim(0, ymax)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc='upper center', bbox_to_anchor=(0.5, -0.2),
              ncol=2 if len(labels) > 5 else len(labels))
    few = min(ns) < MIN_BAND_SEEDS
    ax.set_title(title + ('\n' + band_note(min(ns)) + ' (seeds dashed)' if few else ''),
                 fontsize=10 if few else None)
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
    ax.set_xlabel('x [m]')
    ax.set_ylabel('y [m]')


def arena_legend(fig) -> None:
    """One legend below ``fig`` for what :func:`draw_arena` draws."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch
    handles = [Patch(color='tab:green', alpha=0.9, label='short obstacle'),
               Patch(color='dimgray', alpha=0.9, label='tall obstacle'),
               Line2D([], [], ls='', marker='o', color='red', alpha=0.6, ms=9,
                      label='goal (destination)'),
               Line2D([], [], ls='', marker='o', color='orange', mec='k', ms=7,
                      label='landmark'),
               Line2D([], [], ls='', marker='x', color='blue', label='start A-E')]
    fig.legend(handles=handles, loc='lower center', ncol=len(handles), fontsize=7,
               bbox_to_anchor=(0.5, -0.04))


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
        fig.colorbar(im, ax=ax, fraction=0.046).set_label('Pr(M_pl | x)')
    fig.suptitle('Fig. 4: probability of selecting the place module at the end of learning',
                 fontsize=10)
    arena_legend(fig)
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
        fig.colorbar(im, ax=axes[row, -1], fraction=0.046).set_label('Pr(i | x)')
    fig.suptitle('Fig. 4 for every module: probability of being selected at the end of '
                 'learning', fontsize=10)
    arena_legend(fig)
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
        ax.bar(np.arange(len(STARTS)) + k * width, mean, width,
               yerr=half if np.isfinite(half).all() else None, capsize=2,
               label=f'{label} (n={len(runs)})')
    ax.set_xticks(np.arange(len(STARTS)) + width * (len(labels) - 1) / 2)
    ax.set_xticklabels(STARTS)
    ax.set_xlabel('start point')
    ax.set_ylabel('time to destination [s] (timeout = 60)')
    ax.legend(fontsize=8)
    ax.grid(axis='y', alpha=0.3)
    n = min(len(_runs(results, lb)) for lb in labels)
    ax.set_title('Fig. 5: time to the destination after learning'
                 + (' (95% t-band over seeds)' if n >= MIN_BAND_SEEDS else f'\n({band_note(n)})'))
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


def moving_window(n: int) -> int:
    """Window of the moving average of a run of ``n`` episodes: about a tenth of the run,
    at least 3 (or ``n``) and at most 50 (the paper's block)."""
    return int(min(max(round(n / 10), min(3, n)), 50)) if n > 0 else 1


def moving_average(values: np.ndarray, window: int) -> np.ndarray:
    """Trailing mean over the last ``window`` values (fewer at the start), NaN-aware."""
    values = np.asarray(values, float)
    out = np.full(len(values), np.nan)
    for k in range(len(values)):
        chunk = values[max(0, k - window + 1):k + 1]
        chunk = chunk[np.isfinite(chunk)]
        if chunk.size:
            out[k] = chunk.mean()
    return out


def _run_title(result, what: str, window: int) -> str:
    label = result.spec.get('label', 'run')
    n = len(result.episodes)
    return f'{label}: {what}, {n} episodes (moving average over {window})'


def _mark_divergences(ax, rows: list[dict]) -> None:
    """A dashed line at each episode where the divergence guard reported a module
    (:mod:`clis_learner.core.guard`), labelled with the module."""
    for k, row in enumerate(rows):
        names = [m for m in str(row.get('diverged') or '').split('+') if m and m != 'nan']
        if not names:
            continue
        ax.axvline(k + 1, color='tab:red', ls='--', lw=1.2)
        ax.text(k + 1, 0.5, f' {"+".join(names)} diverged (episode {k + 1})', color='tab:red',
                rotation=90, va='center', ha='right', fontsize=8)


def run_curve(result, path: Path) -> None:
    """The learning of one run (``clis run``'s ``curve.png``), for any length from a few
    episodes: each episode's outcome (reached or not), its moving average
    (:func:`moving_window`), and the success rate of each full block of ``result.block``
    episodes at the block's last episode."""
    reached = np.array([float(r.get('reached', np.nan)) for r in result.episodes])
    n = len(reached)
    x = np.arange(1, n + 1)
    window = moving_window(n)
    fig, ax = plt.subplots(figsize=(8, 4))
    ax.plot(x, reached, '|', color='tab:gray', ms=8, label='episode (1 = reached)')
    ax.plot(x, moving_average(reached, window), '-', marker='.' if n < 30 else None,
            color='tab:blue', lw=2, label=f'moving average ({window} episodes)')
    n_blocks = n // result.block if result.block > 0 else 0
    if n_blocks:
        rate = np.array(result.success_curve()) / result.block
        ax.plot(np.arange(1, n_blocks + 1) * result.block, rate, 's', color='tab:red', ms=7,
                label=f'block of {result.block} episodes (at its last)')
    _mark_divergences(ax, result.episodes)
    ax.set_xlim(0.5, n + 0.5)
    ax.set_ylim(-0.05, 1.05)
    ax.set_xlabel('episode')
    ax.set_ylabel('success (reached the destination)')
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc='upper left')
    ax.set_title(_run_title(result, 'success', window), fontsize=10)
    _save(fig, path)


def run_selection(result, path: Path) -> None:
    """Who acted in each episode of one run (``clis run``'s ``selection.png``): the share
    of the episode's time each module's command was in force, its moving average
    (:func:`moving_window`) and the mean of each full block of ``result.block`` episodes."""
    n = len(result.episodes)
    x = np.arange(1, n + 1)
    window = moving_window(n)
    fig, ax = plt.subplots(figsize=(8, 4))
    n_blocks = n // result.block if result.block > 0 else 0
    for k, name in enumerate(result.modules):
        colour = MODULE_COLOURS.get(name, f'C{k}')
        share = np.array([float(r.get(f'share_{name}', np.nan)) for r in result.episodes])
        ax.plot(x, share, '.', color=colour, alpha=0.35, ms=4)
        ax.plot(x, moving_average(share, window), '-', marker='.' if n < 30 else None,
                color=colour, lw=2, label=f'{name} (moving average over {window})')
        if n_blocks:
            ax.plot(np.arange(1, n_blocks + 1) * result.block,
                    result.selection_shares()[:, k], 's', color=colour, mec='k', ms=7)
    if n_blocks:
        ax.plot([], [], 's', color='white', mec='k',
                label=f'block of {result.block} episodes (at its last)')
    ax.plot([], [], '.', color='gray', alpha=0.5, label='one episode')
    ax.set_xlim(0.5, n + 0.5)
    ax.set_ylim(-0.05, 1.05)
    ax.set_xlabel('episode')
    ax.set_ylabel("share of the episode's time acting")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc='upper left', ncol=2)
    ax.set_title(_run_title(result, 'who acted', window), fontsize=10)
    _save(fig, path)


@contextlib.contextmanager
def sigint_after() -> Iterator[None]:
    """Hold a Ctrl-C (SIGINT) that arrives inside the block and raise it as
    :class:`KeyboardInterrupt` when the block is done: a KeyboardInterrupt raised inside
    matplotlib's renderer comes out as another error (seen: ``ValueError: Invalid bounding
    box``), a traceback instead of the one line of ``clis``. Outside the main thread (no
    signal handlers there) the block runs as it is."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: held.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if held:
        raise KeyboardInterrupt


def draw_all(out: Path, results, summary: dict) -> list[Path]:
    """Draw every figure into ``out``; return the files written. Interrupted (Ctrl-C) or
    failed, it closes the figures it opened."""
    paths = []
    before = set(plt.get_fignums())
    try:
        for name, fn in (('fig3a.png', fig3a), ('fig3a_learning.png', fig3a_learning),
                         ('fig3bc.png', fig3bc), ('fig4.png', fig4),
                         ('fig4_modules.png', fig4_modules),
                         ('fig5.png', fig5), ('diagnostics.png', fig_diagnostics)):
            with sigint_after():
                fn(results, out / name)
            if (out / name).exists():
                paths.append(out / name)
    except BaseException:
        for num in set(plt.get_fignums()) - before:
            plt.close(num)
        raise
    return paths
