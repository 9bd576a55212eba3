"""Whether numba's ``np.dot`` rounds as numpy's does, on this machine.

A compiled loop over a whole episode (docs/benchmarks.md) must keep numpy's arithmetic to keep
the golden digests. The value ``w . b`` and the policy mean ``W b`` are BLAS calls in numpy
(OpenBLAS ``ddot`` and ``dgemv``); numba compiles ``np.dot`` of float64 arrays into calls of
the BLAS that scipy ships. This compares the two on random vectors of the project's feature
sizes and prints the mismatches:

    python tools/dot_rounding.py
"""

from __future__ import annotations

import argparse
import sys

import numba
import numpy as np


@numba.njit(cache=False)
def _dot(a: np.ndarray, b: np.ndarray):
    return np.dot(a, b)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('--draws', type=int, default=300, help='random pairs per size')
    p.add_argument('--seed', type=int, default=0)
    args = p.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    sizes = (3, 7, 16, 33, 64, 100, 250, 450, 513, 1000, 4800)
    ddot = dgemv = 0
    for n in sizes:
        for _ in range(args.draws):
            a = rng.standard_normal(n)
            b = rng.standard_normal(n) * rng.random(n)
            W = rng.standard_normal((2, n))  # noqa: N806 - the paper's W
            ddot += _dot(a, b) != np.dot(a, b)
            dgemv += not np.array_equal(_dot(W, b), W @ b)
    total = len(sizes) * args.draws
    print(f'numba np.dot against numpy: ddot {ddot} of {total} differ, dgemv (2 x n) {dgemv} '
          f'of {total} differ (sizes {", ".join(map(str, sizes))}; numba {numba.__version__}, '
          f'numpy {np.__version__})')
    return 1 if ddot or dgemv else 0


if __name__ == '__main__':
    sys.exit(main())
