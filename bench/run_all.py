"""``make bench``: run every benchmark and record the results with machine and date.

Each ``bench/bench_*.py`` is run as ``python bench/bench_X.py --json FILE``; the collected
results go to ``bench/results/latest.json`` and are rendered into ``docs/benchmarks.md``
between the ``<!-- BENCH -->`` markers (the prose around them is kept).
"""

from __future__ import annotations

import datetime as dt
import json
import os
from pathlib import Path
import platform
import subprocess
import sys
import tempfile

HERE = Path(__file__).resolve().parent
DOC = HERE.parent / 'docs' / 'benchmarks.md'
START, END = '<!-- BENCH -->', '<!-- /BENCH -->'


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


def render(results: dict) -> str:
    m = results['machine']
    lines = [f'Measured {m["date"]} on {m["cpu"]} ({m["cores"]} cores), Python {m["python"]}, '
             f'numpy {m["numpy"]}, scipy {m["scipy"]}, {m["platform"]}.', '',
             '| benchmark | measure | value | goal |', '|---|---|---|---|']
    for name, res in results['benchmarks'].items():
        for row in res.get('rows', []):
            lines.append(f'| {name} | {row["measure"]} | {row["value"]} | '
                         f'{row.get("goal", "")} |')
    return '\n'.join(lines)


def main() -> int:
    results = {'machine': machine(), 'benchmarks': {}}
    failed = []
    for script in sorted(HERE.glob('bench_*.py')):
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
    if START in text and END in text:
        head, rest = text.split(START, 1)
        _, tail = rest.split(END, 1)
        DOC.write_text(f'{head}{START}\n{render(results)}\n{END}{tail}')
    print(render(results))
    if failed:
        print(f'benchmarks failed: {", ".join(failed)}', file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
