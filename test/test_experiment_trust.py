"""`clis experiment`, `clis report` and the figures give what was asked or stop:
--resume only with the same settings, --figures-only keeps experiment.json, no duplicate
conditions, no meaningless bands, figures that draw their data, files with the usual mode."""

from __future__ import annotations

import json
import os
from pathlib import Path
import shutil

from clis_app.cli import main as clis
from clis_app.experiments import figures, report
from clis_app.experiments.runner import JobResult, arena_dict
from cr_sim.core.arena import load_arena
from cr_sim.core.sim import load_sim_params
import matplotlib.pyplot as plt
import numpy as np
import pytest

#: A tiny experiment: 2 learning episodes of View, evaluated before learning (--eval-every 5
#: is longer than the run) and after it.
TINY = ['--conditions', 'view', '--episodes', '2', '--block', '2', '--seeds', '1',
        '--eval-episodes', '1', '--eval-every', '5', '--workers', '1', '--quiet',
        '--train-start', 'starts']


@pytest.fixture(scope='module', autouse=True)
def own_config(tmp_path_factory):
    """A copy of config/ for this module: an edit of the working tree's between the tiny run
    and a --resume of it would change the parameter hash, which --resume rightly refuses."""
    from clis_base.params import config_dir
    copy = tmp_path_factory.mktemp('config') / 'config'
    shutil.copytree(config_dir(), copy)
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv('CLIS_CONFIG_DIR', str(copy))
        yield copy


@pytest.fixture(scope='module')
def tiny(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp('tiny') / 'exp'
    assert clis(['experiment', *TINY, '--out', str(out)]) == 0
    return out


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def _tree(path: Path) -> dict[str, bytes]:
    return {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob('*'))
            if p.is_file()}


# ----------------------------------------------------------------------------- experiment

@pytest.mark.parametrize('change, says', [
    (['--episodes', '4'], 'episodes=2 (now 4)'),
    (['--set', 'common.beta=200.0'], "'common.beta': 200.0"),
    (['--eval-episodes', '2'], 'eval_episodes=1 (now 2)'),
])
def test_resume_refuses_runs_made_with_other_settings(tiny, tmp_path, capsys, change, says):
    out = _copy(tiny, tmp_path / 'exp')
    before = _tree(out)
    capsys.readouterr()
    assert clis(['experiment', *TINY, '--out', str(out), '--resume', *change]) == 2
    err = capsys.readouterr().err
    assert says in err and '--out' in err and 'without --resume' in err, err
    assert len(err.strip().splitlines()) == 1
    assert _tree(out) == before, 'a refused --resume changed OUT'


def test_resume_with_the_same_settings_reuses_the_runs(tiny, tmp_path):
    out = _copy(tiny, tmp_path / 'exp')
    run = next((out / 'runs').glob('*.json'))
    mtime = run.stat().st_mtime_ns
    assert clis(['experiment', *TINY, '--out', str(out), '--resume']) == 0
    assert run.stat().st_mtime_ns == mtime


def test_figures_only_reads_and_keeps_experiment_json(tiny, tmp_path, capsys):
    out = _copy(tiny, tmp_path / 'exp')
    (out / 'fig3a.png').unlink()
    saved = (out / 'experiment.json').read_bytes()
    assert clis(['experiment', '--figures-only', '--out', str(out)]) == 0
    assert (out / 'experiment.json').read_bytes() == saved
    assert (out / 'fig3a.png').stat().st_size > 1000
    assert 'view' in capsys.readouterr().out


def test_figures_only_without_an_experiment_creates_nothing(tmp_path, capsys):
    assert clis(['experiment', '--figures-only', '--out', str(tmp_path / 'none')]) == 2
    assert 'experiment.json' in capsys.readouterr().err
    assert not (tmp_path / 'none').exists()


@pytest.mark.parametrize('conditions', ['view,view', 'view, view ,innate'])
def test_duplicate_conditions_are_refused(tmp_path, capsys, conditions):
    out = tmp_path / 'dup'
    assert clis(['experiment', '--conditions', conditions, '--episodes', '2', '--block', '2',
                 '--out', str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert 'view' in err and 'more than once' in err and len(err.splitlines()) == 1
    assert not out.exists()


def test_episodes_shorter_than_a_block_create_nothing(tmp_path, capsys):
    out = tmp_path / 'short'
    assert clis(['experiment', '--episodes', '10', '--out', str(out)]) == 2
    assert '--block 10' in capsys.readouterr().err
    assert not out.exists()


def test_help_shows_every_default(capsys):
    for cmd in ('experiment', 'report', 'compare'):
        with pytest.raises(SystemExit):
            clis([cmd, '--help'])
        text = ' '.join(capsys.readouterr().out.split())
        if cmd == 'experiment':
            for item in ('--episodes EPISODES learning episodes per run (default: 1000)',
                         '(0..N-1) (default: 5)', '--block BLOCK', '(default: 50)',
                         '(default: wander)', '(default: 10)'):
                assert item in text, (cmd, item)
        if cmd == 'compare':
            assert 'per block (default: 50)' in text and '(default: graph)' in text


def test_summary_header_names_the_block(tiny):
    summary = json.loads((tiny / 'summary.json').read_text())
    assert 'succ/2 first' in summary['table'][0] and 'succ/50' not in summary['table'][0]


def test_report_final_eval_is_the_one_after_learning(tiny, capsys):
    capsys.readouterr()
    assert clis(['report', str(tiny)]) == 0
    out = capsys.readouterr().out
    row = next(line for line in out.splitlines() if line.startswith('| improved:view | 1 | '))
    assert row.endswith('(ep 2) |'), row           # not the evaluation before learning


def test_checkpoints_and_runs_have_the_usual_file_mode(tiny, tmp_path):
    from clis_learner.core.checkpoint import save_checkpoint
    from clis_learner.core.config import load_clis_params
    from clis_modules.core.modules import arena_map, make_modules
    mask = os.umask(0o022)
    try:
        arena = load_arena(None, load_sim_params().robot.radius)
        modules = make_modules(load_clis_params(), 'view', *arena_map(arena))
        path = save_checkpoint(tmp_path / 'c.npz', modules)
        assert path.stat().st_mode & 0o777 == 0o644
        os.umask(0o027)
        assert save_checkpoint(tmp_path / 'd.npz', modules).stat().st_mode & 0o777 == 0o640
    finally:
        os.umask(mask)
    modes = {p.name: p.stat().st_mode & 0o777 for p in (tiny / 'runs').iterdir()}
    assert len(set(modes.values())) == 1, modes     # .npz like .json (the test umask)


# ------------------------------------------------------------------ synthetic runs, report

ARENA = arena_dict(load_arena(None, load_sim_params().robot.radius))


def synthetic_run(label: str, seed: int, n: int, modules=('innate', 'view', 'place'),
                  block: int = 50, eval_every: int = 50, condition: str | None = None
                  ) -> JobResult:
    """A run of ``n`` learning episodes with random outcomes (no simulation)."""
    rng = np.random.default_rng(seed)
    episodes = []
    for ep in range(n):
        share = rng.dirichlet(np.ones(len(modules)))
        row = {'label': label, 'seed': seed, 'phase': 'train', 'episode': ep,
               'reached': float(rng.random() < ep / max(n, 1)), 'duration': 30.0,
               'collisions': 0.0}
        for k, m in enumerate(modules):
            row |= {f'share_{m}': share[k], f'p_{m}': 1 / len(modules), f'v_{m}': 0.1,
                    f'log10c_{m}': -1.0}
        episodes.append(row)
    evals = [{'start': s, 'reached': float(rng.random() < 0.5), 'duration': 20.0}
             for s in figures.STARTS for _ in range(2)]
    points = list(range(0, n + 1, eval_every)) if eval_every else []
    curve = [{'episode': p, 'reached': int(rng.integers(0, 11)), 'n': 10} for p in points]
    grid = np.linspace(0.1, 0.9, 12).reshape(3, 4)
    place_map = {'x': [-0.6, -0.2, 0.2, 0.6], 'y': [-0.4, 0.0, 0.4], 'p': grid.tolist(),
                 'modules': {m: grid.tolist() for m in modules}} if len(modules) > 1 else None
    spec = {'label': label, 'condition': condition or (label if len(modules) == 1
                                                       else 'async'),
            'seed': seed, 'episodes': n, 'block': block}
    return JobResult(spec=spec, modules=list(modules), block=block, episodes=episodes,
                     evals=evals, place_map=place_map, arena=ARENA, seconds=1.0,
                     eval_curve=curve)


def test_report_gives_no_band_below_three_seeds():
    two = [synthetic_run('async', s, 100) for s in (0, 1)]
    text = '\n'.join((report.eval_report(two), report.report(two), report._band_note(two)))
    rows = [line for line in text.splitlines() if line.startswith('| async | 2 |')]
    assert rows and all('±' not in r for r in rows), rows
    assert 'fewer than 3 seeds' in text
    three = [synthetic_run('async', s, 100) for s in (0, 1, 2)]
    assert '±' in report.report(three) and not report._band_note(three)


# -------------------------------------------------------------------------------- figures

@pytest.fixture
def drawn(monkeypatch):
    """The figures the drawing functions make, kept open instead of written."""
    kept = []

    def keep(fig, path):
        kept.append(fig)
        Path(path).write_bytes(b'png')
    monkeypatch.setattr(figures, '_save', keep)
    yield kept
    plt.close('all')


def visible_points(ax) -> int:
    """Data points a reader sees: a line's points if it has markers, else its segments
    (a line of one point without a marker draws nothing), plus drawn bars."""
    count = 0
    for line in ax.lines:
        y = np.asarray(line.get_ydata(), float)
        n = int(np.isfinite(y).sum())
        if line.get_marker() not in (None, '', 'None', ' ') and line.get_visible():
            count += n
        elif line.get_linestyle() not in ('None', '', ' '):
            count += max(n - 1, 0)
    count += sum(1 for p in ax.patches if getattr(p, 'get_height', lambda: 0)() > 0.01)
    return count


def test_fig3a_with_one_evaluation_point_draws_it(drawn, tmp_path):
    runs = [synthetic_run('view', s, 10, modules=('view',), eval_every=50) for s in (0, 1, 2)]
    figures.fig3a(runs, tmp_path / 'f.png')
    assert visible_points(drawn[0].axes[0]) >= 1


def test_fig3a_with_two_seeds_draws_the_seeds_not_a_band(drawn, tmp_path):
    runs = [synthetic_run('async', s, 200) for s in (0, 1)]
    figures.fig3a(runs, tmp_path / 'f.png')
    ax = drawn[0].axes[0]
    assert not ax.collections, 'a t-band with 1 degree of freedom'
    assert 'n=2' in ax.get_title() and len(ax.lines) == 3   # mean + each seed
    runs.append(synthetic_run('async', 2, 200))
    figures.fig3a(runs, tmp_path / 'g.png')
    assert drawn[1].axes[0].collections                  # 3 seeds: the band


def test_fig4_says_what_it_shows(drawn, tmp_path):
    runs = [synthetic_run('async', s, 10) for s in (0, 1, 2)]
    for fn in (figures.fig4, figures.fig4_modules):
        fn(runs, tmp_path / 'f.png')
        fig = drawn[-1]
        maps = [ax for ax in fig.axes if ax.images]
        assert maps and all(ax.get_xlabel() == 'x [m]' and ax.get_ylabel() == 'y [m]'
                            for ax in maps)
        bars = [ax for ax in fig.axes if not ax.images]
        assert bars and all(ax.get_ylabel().startswith('Pr(') for ax in bars)
        legend = ' '.join(t.get_text() for lg in fig.legends for t in lg.get_texts())
        for item in ('obstacle', 'goal', 'landmark', 'start'):
            assert item in legend, (fn.__name__, legend)


@pytest.mark.parametrize('n', [3, 66, 1000])
def test_a_run_of_any_length_draws_its_learning(drawn, tmp_path, n):
    """``clis run``'s curve.png and selection.png (run_curve.write_curve) from its
    episodes.csv."""
    import csv

    from clis_app.graph.curve import write_curve
    rows = synthetic_run('async', 0, n).episodes
    with open(tmp_path / 'episodes.csv', 'w', newline='') as fh:
        w = csv.DictWriter(fh, [k for k in rows[0] if k != 'label'] + ['condition'])
        w.writeheader()
        w.writerows([{**{k: v for k, v in r.items() if k != 'label'}, 'condition': 'async'}
                     for r in rows])
    assert write_curve(tmp_path, 50) is not None
    assert len(drawn) == 2                              # curve.png, selection.png
    for fig in drawn:
        ax = fig.axes[0]
        # every episode shown (its outcome / who acted), and a moving average over them
        assert visible_points(ax) >= n, (n, visible_points(ax))
        assert any(len(line.get_xdata()) == n and line.get_linestyle() == '-'
                   for line in ax.lines)
        blocks = [line for line in ax.lines if line.get_marker() == 's'
                  and len(line.get_xdata())]
        assert len(blocks) >= (1 if n >= 50 else 0)
        assert ax.get_xlabel() == 'episode' and ax.get_title()
