"""Figures of layouts and studies: the picture of an arena with its starts, the forest plot of
Async minus each single module per layout, and View - Innate against the hidden share.

The arena is drawn as the Fig. 4 maps draw it
(:func:`clis_app.experiments.figures.draw_arena`), with what a layout's situations need on
top: the landmarks in their colours, each start's heading, its straight line to the
destination, and the floor from which the destination is hidden.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import itertools
import math
from pathlib import Path

from cr_sim.core.arena import Arena
from cr_sim.core.geometry import segments_blocked
from cr_sim.core.layout import SITUATIONS, hidden_share, start_situations
import numpy as np

from clis_app.experiments.figures import _save, draw_arena, plt
from clis_app.experiments.runner import arena_dict

__all__ = ['draw_layout', 'layout_picture', 'layout_gallery', 'ForestRow', 'forest_plot',
           'hidden_scatter']

#: Colour of a start's straight line to the destination, per situation.
_LINE = {'clear': 'tab:blue', 'short_across': 'tab:orange', 'hidden': 'tab:purple'}
_WORDS = {'clear': 'A-C: line clear, goal visible', 'short_across': 'D: short obstacle across',
          'hidden': 'E: tall obstacle hides goal'}


def _hidden_mask(arena: Arena, robot_radius: float, res: float
                 ) -> tuple[np.ndarray, tuple[float, float, float, float]]:
    """1 where the robot fits and the destination is hidden, NaN elsewhere; and its extent."""
    x0, y0, x1, y1 = arena.bounds
    xs, ys = np.arange(x0 + res / 2, x1, res), np.arange(y0 + res / 2, y1, res)
    px, py = np.meshgrid(xs, ys)
    fits = np.array([arena.gap(x, y, robot_radius) >= 0.0 for x, y in zip(px.ravel(),
                                                                         py.ravel())])
    d = arena.destination
    tall = arena.box_array(tall_only=True)
    cells = np.stack([px.ravel(), py.ravel()], axis=1)
    hidden = (segments_blocked(d.x, d.y, cells, tall) if len(tall)
              else np.zeros(len(cells), bool))
    mask = np.where(fits & hidden, 1.0, np.nan).reshape(px.shape)
    return mask, (x0, x1, y0, y1)


def draw_layout(ax, arena: Arena, robot_radius: float, res: float = 0.025,
                labels: bool = True) -> dict[str, str]:
    """Draw ``arena`` on ``ax`` with its starts' situations; return :func:`start_situations`."""
    mask, extent = _hidden_mask(arena, robot_radius, res)
    ax.imshow(mask, origin='lower', extent=extent, cmap='Greys', vmin=0, vmax=4,
              interpolation='nearest', zorder=0)
    draw_arena(ax, arena_dict(arena))
    for lm in arena.landmarks:
        ax.plot(lm.x, lm.y, 'o', color=lm.colour, ms=9 if labels else 6, mec='k',
                clip_on=False, zorder=5)
        if labels:
            ax.annotate(lm.name, (lm.x, lm.y), xytext=(0, 0), textcoords='offset points',
                        fontsize=6, ha='center', va='center', zorder=6,
                        color='white' if lm.colour in ('blue', 'green', 'red') else 'black')
    d = arena.destination
    checks = start_situations(arena, robot_radius)
    for s in arena.starts:
        kind = SITUATIONS.get(s.name)
        colour = _LINE.get(kind, 'grey')
        ax.plot([s.x, d.x], [s.y, d.y], '--', color=colour, lw=1.2, zorder=3)
        ax.annotate('', xy=(s.x + 0.22 * math.cos(s.heading), s.y + 0.22 * math.sin(s.heading)),
                    xytext=(s.x, s.y), arrowprops={'arrowstyle': '->', 'color': 'blue',
                                                   'lw': 1.2}, zorder=4)
        ax.add_patch(plt.Circle((s.x, s.y), robot_radius, fill=False, color='blue', lw=0.8,
                                zorder=4))
        if checks.get(s.name):
            ax.plot(s.x, s.y, 'X', color='red', ms=12, zorder=7)
    return checks


def _legend(fig, ncol: int, below: float) -> None:
    """The legend of :func:`draw_layout`, below ``fig``."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch
    handles = [Patch(color='tab:green', alpha=0.9, label='short obstacle'),
               Patch(color='dimgray', alpha=0.9, label='tall obstacle'),
               Patch(color='lightgrey', label='goal hidden from here'),
               Line2D([], [], ls='', marker='o', color='red', alpha=0.6, ms=9,
                      label='goal (destination)'),
               Line2D([], [], ls='', marker='o', color='w', mec='k', ms=8,
                      label='landmark (its colour)'),
               Line2D([], [], color='blue', marker='x', ls='-', label='start, heading')]
    handles += [Line2D([], [], color=c, ls='--', label=_WORDS[k]) for k, c in _LINE.items()]
    fig.legend(handles=handles, loc='lower center', ncol=ncol, fontsize=7.5,
               bbox_to_anchor=(0.5, below))


def layout_gallery(arenas: Sequence[tuple[str, Arena]], robot_radius: float,
                   path: Path) -> None:
    """Every layout of a study, small, titled with its name and hidden share (a start out of
    its situation is marked with a red cross)."""
    ncol = min(6, len(arenas))
    nrow = math.ceil(len(arenas) / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(2.7 * ncol, 2.9 * nrow + 0.6),
                             squeeze=False)
    for ax in axes.ravel()[len(arenas):]:
        ax.axis('off')
    for ax, (name, arena) in zip(axes.ravel(), arenas):
        draw_layout(ax, arena, robot_radius, res=0.05, labels=False)
        ax.set_title(f'{name}: goal hidden from {100 * hidden_share(arena, robot_radius):.0f}%',
                     fontsize=8)
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_xlabel('')
        ax.set_ylabel('')
    fig.suptitle('The layouts of the study (starts A-E, their straight lines to the goal)',
                 fontsize=10)
    _legend(fig, 5, -0.06 / nrow)
    _save(fig, path)


def layout_picture(arena: Arena, robot_radius: float, path: Path, title: str) -> dict[str, str]:
    """The picture of one layout (``clis arena show``), saved to ``path``; returns
    :func:`start_situations` (a start out of its situation is marked with a red cross)."""
    fig, ax = plt.subplots(figsize=(6.2, 5.2 * arena.height / arena.width + 1.6))
    checks = draw_layout(ax, arena, robot_radius)
    share = hidden_share(arena, robot_radius)
    bad = [n for n, why in checks.items() if why]
    state = ("starts in the paper's situations" if not bad
             else f'NOT in their situation: {", ".join(bad)}')
    ax.set_title(f'{title}\ngoal hidden from {100 * share:.1f}% of the free floor (shaded); '
                 f'{state}', fontsize=9)
    _legend(fig, 3, -0.08)
    _save(fig, path)
    return checks


@dataclass(frozen=True)
class ForestRow:
    """One interval of a forest plot.

    Attributes
    ----------
    label : str
        The band it is drawn in (a layout, or the aggregate over layouts).
    series : str
        What it compares (``Async - view``...): its colour within the band.
    mean, half : float
        The mean and the half-width of its 95% interval (NaN: none).
    aggregate : bool
        The aggregate over layouts (a diamond).
    above : bool
        The band's verdict: Async above every single module (the band is shaded).
    """

    label: str
    series: str
    mean: float
    half: float
    aggregate: bool = False
    above: bool = False


#: Colours of the forest plot's series: each single module, then the leave-one-out choice.
_SERIES = {'Async - innate': 'tab:blue', 'Async - view': 'tab:purple',
           'Async - place': 'tab:green', 'Async - best single, leave one out': 'black'}
_MORE = ('tab:brown', 'tab:olive', 'tab:cyan', 'tab:pink')


def forest_plot(panels: dict[str, dict[str, list[ForestRow]]], path: Path, title: str,
                xlabel: str) -> None:
    """A forest plot: one column per protocol, one row of panels per preset.

    Parameters
    ----------
    panels : dict
        ``{protocol: {preset: rows}}``. Each layout is a band of rows, one per series (the
        colours of :data:`_SERIES`), the aggregate over layouts last (diamonds); a band whose
        rows have ``above`` is shaded.
    path : Path
        The PNG written.
    title, xlabel : str
        The figure's title and the x axis' label.
    """
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch
    protocols = list(panels)
    presets = list(dict.fromkeys(p for by in panels.values() for p in by))
    series = list(dict.fromkeys(r.series for by in panels.values() for rows in by.values()
                                for r in rows))
    known = list(_SERIES)
    first = list(series)
    series.sort(key=lambda s: (known.index(s) if s in known else len(known), first.index(s)))
    extra = itertools.cycle(_MORE)
    colours = {s: _SERIES.get(s) or next(extra) for s in series}
    bands = {}
    for p in presets:
        rows = [r for by in panels.values() for r in by.get(p, [])]
        bands[p] = (list(dict.fromkeys(r.label for r in rows if not r.aggregate))
                    + list(dict.fromkeys(r.label for r in rows if r.aggregate)))
    heights = [len(bands[p]) + 0.8 for p in presets]
    fig, axes = plt.subplots(len(presets), len(protocols), squeeze=False, sharex=True,
                             sharey='row', figsize=(3.9 * len(protocols) + 1.8,
                                                    0.36 * sum(heights) + 1.6),
                             gridspec_kw={'height_ratios': heights})
    step = min(0.2, 0.84 / max(len(series), 1))           # a band's rows
    offset = {s: ((len(series) - 1) / 2 - k) * step for k, s in enumerate(series)}
    for i, p in enumerate(presets):
        labels = bands[p]
        ypos = {lb: len(labels) - 1 - k for k, lb in enumerate(labels)}
        n_aggregate = len({r.label for by in panels.values() for r in by.get(p, [])
                           if r.aggregate})
        for j, proto in enumerate(protocols):
            ax = axes[i][j]
            rows = panels[proto].get(p, [])
            for lb in {r.label for r in rows if r.above}:
                ax.axhspan(ypos[lb] - 0.5, ypos[lb] + 0.5, color='#d9f2d9', zorder=0)
            ax.axvline(0.0, color='k', lw=0.8)
            for r in rows:
                y = ypos[r.label] + offset[r.series]
                c = colours[r.series]
                if math.isfinite(r.half):
                    ax.plot([r.mean - r.half, r.mean + r.half], [y, y], '-', color=c,
                            lw=1.8 if r.aggregate else 1.2)
                ax.plot(r.mean, y, 'D' if r.aggregate else 'o', color=c,
                        ms=5.5 if r.aggregate else 3.2,
                        mfc=c if r.aggregate or math.isfinite(r.half) else 'white')
            if n_aggregate:
                ax.axhline(n_aggregate - 0.5, color='grey', lw=0.6, ls=':')
            ax.set_ylim(-0.6, len(labels) - 0.4)
            ax.grid(axis='x', alpha=0.3)
            ax.tick_params(axis='x', labelsize=8)
            if i == 0:
                ax.set_title(f'protocol {proto}', fontsize=10)
            if i == len(presets) - 1:
                ax.set_xlabel(xlabel, fontsize=9)
            if not rows:
                ax.text(0.5, 0.5, 'no runs', transform=ax.transAxes, ha='center',
                        va='center', fontsize=8, color='grey')
        axes[i][0].set_yticks(list(ypos.values()), list(ypos.keys()), fontsize=7.5)
        axes[i][0].set_ylabel(p, fontsize=9, rotation=0, ha='right', va='center',
                              fontweight='bold', labelpad=6)
    handles = [Line2D([], [], color=colours[s], marker='o', ms=4, label=s) for s in series]
    handles += [Line2D([], [], color='grey', marker='D', ls='', ms=6,
                       label='over layouts (95% CI over layouts)'),
                Line2D([], [], color='grey', marker='o', mfc='white', ls='', ms=4,
                       label='fewer than 3 seeds: no interval'),
                Patch(color='#d9f2d9', label='Async above every single module')]
    height = fig.get_size_inches()[1]
    fig.legend(handles=handles, loc='upper center', fontsize=8, ncol=len(handles),
               bbox_to_anchor=(0.5, 0.0))
    fig.suptitle(title, fontsize=10, y=1.0 + 0.3 / height)
    _save(fig, path)


def hidden_scatter(points: Sequence[tuple[str, str, str, float, float, float, bool]],
                   path: Path, title: str) -> None:
    """View - Innate (y, points, with its 95% interval) against the hidden share (x, %), one
    panel per protocol, one point per layout and preset: ``(protocol, preset, label, share,
    mean, half, generated)``. The generated layouts are filled, with a line fitted through
    them per preset; the layouts read from files are open markers, labelled."""
    from matplotlib.lines import Line2D
    protocols = list(dict.fromkeys(p[0] for p in points))
    presets = list(dict.fromkeys(p[1] for p in points))
    colours = dict(zip(presets, ('tab:blue', 'tab:red', 'tab:green', 'tab:purple',
                                 'tab:brown', 'tab:olive')))
    fig, axes = plt.subplots(1, len(protocols), figsize=(4.2 * len(protocols) + 0.8, 4.4),
                             sharey=True, sharex=True, squeeze=False)
    fits = []
    for ax, proto in zip(axes[0], protocols):
        ax.axhline(0.0, color='k', lw=0.8)
        for _, preset, label, share, mean, half, generated in (p for p in points
                                                               if p[0] == proto):
            c = colours[preset]
            if math.isfinite(half):
                ax.plot([100 * share] * 2, [mean - half, mean + half], '-', color=c,
                        alpha=0.3, lw=1)
            ax.plot(100 * share, mean, 'o', color=c, mfc=c if generated else 'white', ms=5,
                    alpha=0.85)
            if not generated:
                ax.annotate(label, (100 * share, mean), xytext=(4, 3),
                            textcoords='offset points', fontsize=7, color=c)
        for preset in presets:
            sel = [p for p in points if p[0] == proto and p[1] == preset and p[6]]
            xs = np.array([100 * p[3] for p in sel])
            ys = np.array([p[4] for p in sel])
            if len(xs) >= 3 and np.ptp(xs) > 0:
                slope, icpt = np.polyfit(xs, ys, 1)
                grid = np.array([xs.min(), xs.max()])
                ax.plot(grid, icpt + slope * grid, '-', color=colours[preset], lw=1.2)
                fits.append(f'{proto}, {preset}: {slope:+.2f} points per %')
        ax.set_title(proto, fontsize=10)
        ax.set_xlabel('goal hidden from [% of the free floor]', fontsize=8)
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel('View - Innate, final evaluated success [points]', fontsize=8)
    handles = [Line2D([], [], color=colours[g], marker='o', ls='', label=f'preset {g}')
               for g in presets]
    handles += [Line2D([], [], color='grey', marker='o', ls='', label='generated layout'),
                Line2D([], [], color='grey', marker='o', mfc='white', ls='',
                       label='layout from a file'),
                Line2D([], [], color='grey', ls='-', label='least-squares line (generated)')]
    fig.legend(handles=handles, loc='lower center', ncol=len(handles), fontsize=8,
               bbox_to_anchor=(0.5, -0.08))
    fig.suptitle(title + ('\nslopes: ' + '; '.join(fits) if fits else ''), fontsize=9)
    _save(fig, path)
