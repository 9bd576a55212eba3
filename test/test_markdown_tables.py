"""Every Markdown table the project writes renders: each row has its header's number of cells
(a ``|`` inside a cell must be escaped, ``\\|``). Checked on the tracked .md files,
on what `clis report` and `clis compare` print and on the benchmark table bench/run_all.py
writes into docs/benchmarks.md."""

from __future__ import annotations

from pathlib import Path
import re
import subprocess
import sys

from clis_app.experiments import compare, report
import numpy as np
import pytest
from test_experiment_trust import synthetic_run

REPO = Path(__file__).resolve().parent.parent
_SEPARATOR = re.compile(r'^\|?\s*:?-{3,}:?\s*(\|\s*:?-{3,}:?\s*)*\|?\s*$')


def cells(row: str) -> list[str]:
    """The cells of a table row as GitHub renders them: split at every ``|`` that is not
    escaped (also inside backticks), without the outer pipes."""
    row = row.strip()
    row = row[1:] if row.startswith('|') else row
    row = row[:-1] if row.endswith('|') and not row.endswith('\\|') else row
    return re.split(r'(?<!\\)\|', row)


def bad_rows(text: str) -> list[str]:
    """Rows whose cell count differs from their table's header, as ``line N: ...``."""
    lines = text.splitlines()
    bad, fenced, k = [], False, 0
    while k < len(lines):
        line = lines[k]
        if line.lstrip().startswith(('```', '~~~')):
            fenced = not fenced
        if (not fenced and line.lstrip().startswith('|') and k + 1 < len(lines)
                and _SEPARATOR.match(lines[k + 1].strip())):
            n = len(cells(line))
            k += 2
            while k < len(lines) and lines[k].lstrip().startswith('|'):
                if len(cells(lines[k])) != n:
                    bad.append(f'line {k + 1}: {len(cells(lines[k]))} cells, header {n}: '
                               f'{lines[k][:100]}')
                k += 1
            continue
        k += 1
    return bad


def tracked_markdown() -> list[Path]:
    out = subprocess.run(['git', 'ls-files', '*.md'], cwd=REPO, capture_output=True,
                         text=True)
    if out.returncode != 0:
        pytest.skip('not a git checkout')
    return [REPO / p for p in out.stdout.split()]


def test_the_checker_sees_a_broken_row():
    assert bad_rows('| a | b |\n|---|---|\n| 1 | x|y |\n') and not bad_rows(
        '| a | b |\n|---|---|\n| 1 | x\\|y |\n')


@pytest.mark.parametrize('path', tracked_markdown(), ids=lambda p: str(p.relative_to(REPO)))
def test_tracked_markdown_tables_render(path):
    assert not bad_rows(path.read_text()), bad_rows(path.read_text())


def test_clis_report_tables_render():
    runs = ([synthetic_run('innate', s, 150, modules=('innate',)) for s in range(3)]
            + [synthetic_run('view', s, 150, modules=('view',)) for s in range(2)]
            + [synthetic_run('async', s, 150) for s in range(3)])
    text = report.eval_report(runs) + '\n\n' + report.report(runs)
    assert 'Pr(i\\|x0)' in text and text.count('\n|') > 10
    assert not bad_rows(text), bad_rows(text)


def test_clis_compare_table_renders():
    a = {f'a{s}': np.random.default_rng(s).random(100) < 0.5 for s in range(3)}
    b = {f'b{s}': np.random.default_rng(9 + s).random(100) < 0.5 for s in range(2)}
    text = compare.table(compare.compare(a, b, 50), 'graph', 'headless', 3, 2)
    assert not bad_rows(text), bad_rows(text)


def test_bench_table_renders():
    sys.path.insert(0, str(REPO / 'bench'))
    try:
        import run_all
    finally:
        sys.path.remove(str(REPO / 'bench'))
    machine = {'date': 'D', 'cpu': 'C', 'cores': 2, 'python': '3', 'numpy': '2', 'scipy': '1',
               'platform': 'P'}
    rows = [{'measure': 'real-time factor: processes | one process', 'value': '34.8x | 41.0x',
             'goal': '>= 20x'},
            {'measure': 'idle CPU: A | B | C', 'value': '1% | 1% | 100%'},
            {'measure': 'already escaped \\| once', 'value': '1'}]
    text = run_all.render({'machine': machine, 'benchmarks': {'bench_x': {'rows': rows}}})
    assert text.count('\n| bench_x') == 3
    assert not bad_rows(text), bad_rows(text)
