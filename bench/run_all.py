"""``make bench``: run every benchmark and record the results with machine and date.

Each ``bench/bench_*.py`` is run as ``python bench/bench_X.py --json FILE``; the collected
results go to ``bench/results/latest.json`` and are rendered into ``docs/benchmarks.md``
between the ``<!-- BENCH -->`` markers (the prose around them is kept).

    python bench/run_all.py [--only bench_gym,bench_learning]

``--only`` runs the named benchmarks and keeps the other benchmarks' rows of the table as they
were (marked with the date they were measured). The learning benchmarks (:data:`LEARNING`:
how CLIS learns and localizes through the standard path, an hour and more of runs) are not
speed measurements: they are run by hand and recorded in docs/robots.md.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
from pathlib import Path
import platform
import re
import subprocess
import sys
import tempfile

HERE = Path(__file__).resolve().parent
DOC = HERE.parent / 'docs' / 'benchmarks.md'
START, END = '<!-- BENCH -->', '<!-- /BENCH -->'
#: The benchmarks of learning, not of speed (module docstring): never run by ``make bench``.
LEARNING = frozenset({'bench_robots', 'bench_localization'})
#: 'The rows of A, B are from DATE UTC (a remark).' in the table's first line
_KEPT = re.compile(r'The rows of (.+?) are from (.+? UTC(?: \([^)]*\))?)\.')


def machine() -> dict:
    cpu = ''
    try:
        for line in Path('/proc/cpuinfo').read_text().splitlines():
            if line.startswith('model name'):
                cpu = line.split(':', 1)[1].strip()
                break
    except OSError:
        pass
    import numpy
    import scipy
    return {'date': dt.datetime.now(dt.timezone.utc).strftime('%Y-%m-%d %H:%M UTC'),
            'cpu': cpu or platform.processor(), 'cores': os.cpu_count(),
            'python': platform.python_version(), 'numpy': numpy.__version__,
            'scipy': scipy.__version__, 'platform': platform.platform()}


def render(results: dict, kept: list[str] | None = None, kept_note: str = '') -> str:
    m = results['machine']
    lines = [f'Measured {m["date"]} on {m["cpu"]} ({m["cores"]} cores), Python {m["python"]}, '
             f'numpy {m["numpy"]}, scipy {m["scipy"]}, {m["platform"]}.'
             + (f' {kept_note}' if kept else ''), '',
             '| benchmark | measure | value | goal |', '|---|---|---|---|']
    for name, res in results['benchmarks'].items():
        for row in res.get('rows', []):
            cells = [name, row['measure'], row['value'], row.get('goal', '')]
            lines.append('| ' + ' | '.join(md_cell(c) for c in cells) + ' |')
    return '\n'.join(lines + (kept or []))


def md_cell(value: object) -> str:
    """``value`` as one Markdown table cell: a ``|`` in it (``a | b`` in a measure or value)
    is escaped so that it does not end the cell."""
    return re.sub(r'(?<!\\)\|', r'\\|', str(value)).replace('\n', ' ')


def _old_rows(text: str, skip: set[str]) -> tuple[list[str], dict[str, str]]:
    """Table rows of benchmarks not in ``skip`` from the current table, and the date each of
    those benchmarks was measured (a row kept from an earlier run keeps that run's date)."""
    if START not in text or END not in text:
        return [], {}
    table = text.split(START, 1)[1].split(END, 1)[0]
    date, earlier = '', {}
    for line in table.splitlines():
        if line.startswith('Measured '):
            date = line.split(' on ', 1)[0][len('Measured '):]
            for names, when in re.findall(_KEPT, line):
                earlier.update({n.strip(): when for n in names.split(',')})
    rows = [line for line in table.splitlines()
            if line.startswith('| bench_') and line.split('|')[1].strip() not in skip]
    dates = {name: earlier.get(name, date)
             for name in {r.split('|')[1].strip() for r in rows}}
    return rows, dates


def _kept_note(dates: dict[str, str]) -> str:
    """'The rows of A, B are from D1. The rows of C are from D2.'"""
    by_date: dict[str, list[str]] = {}
    for name, when in sorted(dates.items()):
        by_date.setdefault(when, []).append(name)
    return ' '.join(f'The rows of {", ".join(names)} are from {when}.'
                    for when, names in sorted(by_date.items()))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--only', help='comma-separated benchmark names (default: all)')
    args = ap.parse_args()
    scripts = sorted(s for s in HERE.glob('bench_*.py') if s.stem not in LEARNING)
    if args.only:
        names = set(args.only.split(','))
        unknown = names - {s.stem for s in scripts}
        if unknown:
            print(f'unknown benchmarks: {", ".join(sorted(unknown))}', file=sys.stderr)
            return 2
        scripts = [s for s in scripts if s.stem in names]
    results = {'machine': machine(), 'benchmarks': {}}
    failed = []
    for script in scripts:
        with tempfile.NamedTemporaryFile(suffix='.json', delete=False) as fh:
            out = Path(fh.name)
        print(f'== {script.name}', flush=True)
        proc = subprocess.run([sys.executable, str(script), '--json', str(out)])
        if proc.returncode != 0 or not out.stat().st_size:
            failed.append(script.name)
            continue
        results['benchmarks'][script.stem] = json.loads(out.read_text())
        out.unlink()
    (HERE / 'results').mkdir(exist_ok=True)
    (HERE / 'results' / 'latest.json').write_text(json.dumps(results, indent=2))
    text = DOC.read_text() if DOC.exists() else f'# Benchmarks\n\n{START}\n{END}\n'
    kept, dates = _old_rows(text, {s.stem for s in scripts}) if args.only else ([], {})
    note = _kept_note(dates) if kept else ''
    table = render(results, kept, note)
    if START in text and END in text:
        head, rest = text.split(START, 1)
        _, tail = rest.split(END, 1)
        DOC.write_text(f'{head}{START}\n{table}\n{END}{tail}')
    print(table)
    if failed:
        print(f'benchmarks failed: {", ".join(failed)}', file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
