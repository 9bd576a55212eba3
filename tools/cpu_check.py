"""The tests that pin results bit for bit, under the CPU kernels users' machines pick.

numpy's BLAS (OpenBLAS, shipped in numpy's wheel) picks its kernels by CPU at load time, numpy
picks the SIMD loops of its ufuncs by CPU (its dispatch), and numba compiles for the host CPU:
the same code can round differently on another machine. This runs the tests marked ``bits``
(``pytest -m "bits and not ros"``) once per combination below, choosing each by the variables
the libraries read (``OPENBLAS_CORETYPE``, ``NPY_DISABLE_CPU_FEATURES``, ``NUMBA_CPU_NAME``),
and prints one line per combination: the kernels that were in force (as the libraries report
them) and the tests' result. A combination the host CPU cannot run (AVX-512 kernels on a CPU
without AVX-512) is reported as skipped, never as passed.

    make test-cpus                       # or:
    python tools/cpu_check.py            # every combination (about 1 min each on 2 cores)
    python tools/cpu_check.py --list     # the combinations
    python tools/cpu_check.py --only skylakex-host,haswell-avx2 -- -k coop

Run it before every change that touches arithmetic (docs/design.md, "Bit for bit: on which
CPUs"). Each combination's pytest output is in ``log/cpu_check/NAME.txt``. Exit status 0 when
every combination that ran passed.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
import json
import os
from pathlib import Path
import re
import subprocess
import sys
import time

REPO = Path(__file__).resolve().parent.parent

# numpy's dispatch levels, named by what is left after disabling the ones above
AVX512 = 'AVX512_SPR AVX512_ICL X86_V4'
AVX2_OFF = AVX512 + ' X86_V3'


@dataclass(frozen=True)
class Combination:
    """One set of kernels: OpenBLAS's core type, numpy's disabled dispatch targets, numba's
    CPU name (None: the library's own choice for this host)."""

    name: str
    coretype: str
    npy_disable: str | None = None
    numba_cpu: str | None = None
    needs: tuple[str, ...] = ()      # /proc/cpuinfo flags the kernels execute

    def env(self) -> dict[str, str]:
        env = {'OPENBLAS_CORETYPE': self.coretype}
        if self.npy_disable:
            env['NPY_DISABLE_CPU_FEATURES'] = self.npy_disable
        if self.numba_cpu:
            env['NUMBA_CPU_NAME'] = self.numba_cpu
        return env

    def describe(self) -> str:
        npy = {None: 'host', AVX512: 'AVX2', AVX2_OFF: 'baseline'}.get(self.npy_disable,
                                                                       self.npy_disable)
        return (f'OPENBLAS_CORETYPE={self.coretype} numpy={npy} '
                f'numba={self.numba_cpu or "host"}')


_SKX = ('avx512f', 'avx512dq', 'avx512bw', 'avx512vl')
_HSW = ('avx2', 'fma')
COMBINATIONS = (
    Combination('skylakex-host', 'SkylakeX', needs=_SKX),
    Combination('skylakex-avx2', 'SkylakeX', AVX512, needs=_SKX),
    Combination('haswell-host', 'Haswell', needs=_HSW),
    Combination('haswell-avx2', 'Haswell', AVX512, needs=_HSW),
    Combination('zen-host', 'Zen', needs=_HSW),
    Combination('zen-avx2', 'Zen', AVX512, needs=_HSW),
    Combination('sandybridge-host', 'Sandybridge', needs=('avx',)),
    Combination('sandybridge-avx2', 'Sandybridge', AVX512, needs=('avx',)),
    Combination('prescott-host', 'Prescott'),
    Combination('prescott-avx2', 'Prescott', AVX512),
    Combination('haswell-baseline', 'Haswell', AVX2_OFF, needs=_HSW),
    Combination('haswell-avx2-numba-haswell', 'Haswell', AVX512, 'haswell', needs=_HSW),
    Combination('skylakex-host-numba-generic', 'SkylakeX', numba_cpu='generic', needs=_SKX),
)

# what the libraries say is in force (run under each combination's environment)
PROBE = """
import json, numpy as np, threadpoolctl
from numpy._core._multiarray_umath import __cpu_features__ as feats
blas = [i.get('architecture', '?') for i in threadpoolctl.threadpool_info()
        if i.get('user_api') == 'blas']
top = [f for f in ('AVX512_SPR', 'AVX512_ICL', 'X86_V4', 'X86_V3', 'X86_V2') if feats.get(f)]
print(json.dumps({'blas': blas[0] if blas else '?', 'numpy': top[0] if top else 'baseline'}))
"""


def cpu_flags() -> set[str]:
    """The host CPU's flags (/proc/cpuinfo); empty where it cannot be read."""
    try:
        text = Path('/proc/cpuinfo').read_text()
    except OSError:
        return set()
    m = re.search(r'^flags\s*:\s*(.*)$', text, re.M)
    return set(m.group(1).split()) if m else set()


def probe(env: dict[str, str]) -> dict[str, str]:
    out = subprocess.run([sys.executable, '-c', PROBE], env=env, capture_output=True,
                         text=True, timeout=120)
    if out.returncode != 0:
        return {'blas': 'error', 'numpy': out.stderr.strip().splitlines()[-1:]}
    return json.loads(out.stdout.strip().splitlines()[-1])


def summary(text: str) -> str:
    """pytest's closing counts ('283 passed', '1 failed, 282 passed')."""
    lines = [ln for ln in text.splitlines() if re.search(r'\d+ (passed|failed|error)', ln)]
    if not lines:
        return 'no result'
    return re.sub(r'[= ]*(in [\d.]+s.*)?$', '', lines[-1].strip('= ')).strip()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('--list', action='store_true', help='print the combinations and exit')
    p.add_argument('--only', default='', help='comma-separated combination names')
    p.add_argument('--workers', type=int, default=2, help='pytest-xdist workers per run')
    p.add_argument('pytest_args', nargs='*', help='more pytest arguments (after --)')
    args = p.parse_args(argv)
    combos = COMBINATIONS
    if args.only:
        names = [n.strip() for n in args.only.split(',') if n.strip()]
        unknown = sorted(set(names) - {c.name for c in COMBINATIONS})
        if unknown:
            p.error(f'unknown combination(s) {", ".join(unknown)}: see --list')
        combos = tuple(c for c in COMBINATIONS if c.name in names)
    if args.list:
        for c in combos:
            print(f'{c.name:30s} {c.describe()}')
        return 0
    flags = cpu_flags()
    logs = REPO / 'log' / 'cpu_check'
    logs.mkdir(parents=True, exist_ok=True)
    base = {k: v for k, v in os.environ.items()
            if k not in ('OPENBLAS_CORETYPE', 'NPY_DISABLE_CPU_FEATURES', 'NUMBA_CPU_NAME')}
    print(f'tests: pytest -m "bits and not ros" {" ".join(args.pytest_args)}; '
          f'logs in {logs.relative_to(REPO)}/', flush=True)
    failed = ran = 0
    for c in combos:
        missing = [f for f in c.needs if flags and f not in flags]
        if missing:
            print(f'{c.name:30s} skipped: this CPU lacks {" ".join(missing)}', flush=True)
            continue
        env = {**base, **c.env()}
        seen = probe(env)
        cmd = [sys.executable, '-m', 'pytest', '-m', 'bits and not ros', '-q',
               '-p', 'no:cacheprovider', '-o', 'addopts=-ra --strict-markers']
        if args.workers > 1:
            cmd += ['-n', str(args.workers), '--dist', 'loadscope']
        t0 = time.monotonic()
        out = subprocess.run(cmd + args.pytest_args, cwd=REPO, env=env, capture_output=True,
                             text=True)
        took = time.monotonic() - t0
        (logs / f'{c.name}.txt').write_text(out.stdout + out.stderr)
        ok = out.returncode == 0
        ran += 1
        failed += not ok
        bad = re.findall(r'^FAILED (\S+)', out.stdout, re.M)
        print(f'{c.name:30s} blas={seen["blas"]:11s} numpy={seen["numpy"]:10s} '
              f'numba={c.numba_cpu or "host":8s} {"pass" if ok else "FAIL"}: '
              f'{summary(out.stdout)} ({took:.0f} s)', flush=True)
        for b in bad:
            print(f'    {b}', flush=True)
    print(f'{ran - failed} of {ran} combinations passed'
          + (f', {len(combos) - ran} skipped' if ran < len(combos) else ''))
    return 1 if failed or not ran else 0


if __name__ == '__main__':
    sys.exit(main())
