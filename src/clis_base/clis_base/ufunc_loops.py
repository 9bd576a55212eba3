"""numpy's own ``exp`` and ``arctan2`` (and its order of ``sum``) inside compiled kernels, bit
for bit.

numpy computes ``exp`` and ``arctan2`` of float64 arrays with SIMD code chosen for the CPU at
import (AVX-512 here), whose results differ from the C library's (``math.exp``, numba's) in the
last bit for a few % of the inputs. A kernel that calls ``math.exp`` is therefore not
bit-identical to numpy code, and kernels used to stop before every ``exp`` and ``arctan2``,
return to Python for the numpy call, and continue in another kernel.

This module calls, from a kernel, the very inner loop that numpy's ufunc runs for
``float64`` (the ``d->d`` loop of ``np.exp``, ``dd->d`` of ``np.arctan2``: the function
pointers of the ufunc object, public C API ``PyUFuncObject.functions``), so the results are
numpy's by construction. The loop addresses differ from process to process: they are read at
import into :data:`LOOPS` and passed to the kernels as an argument (a compiled function keeps
no address, so numba's disk cache stays valid). At import the loops are checked against numpy
on a few thousand inputs; if that fails (another numpy layout), :data:`LOOPS` holds zeros and
the kernels fall back to ``math.exp`` / ``math.atan2`` (correct, not numpy's bits; a warning
says so). Without numba the functions below are numpy calls.

:func:`pairwise_sum` adds in ``np.sum``'s order (its pairwise summation), for kernels that sum
what numpy code summed.
"""

from __future__ import annotations

import ctypes
import importlib.metadata
import warnings

import numpy as np

try:  # pragma: no cover - exercised by whichever branch is installed
    import numba

    HAVE_NUMBA = True

    def njit(fn):
        """As :func:`cr_sim.core.kernels.njit` (which imports this module)."""
        return numba.njit(cache=True, nogil=True)(fn)
except ImportError:  # pragma: no cover
    HAVE_NUMBA = False

    def njit(fn):
        """numba is not installed: run ``fn`` as plain Python (same results, slower)."""
        return fn

__all__ = ['LOOPS', 'CHECKED_ON', 'numpy_version', 'supported', 'exp_into', 'arctan2_into',
           'block_sum', 'pairwise_sum']

#: The numpy versions (major.minor) whose ``PyUFuncObject`` layout :func:`_loop_of` was checked
#: on (requirements-py.txt pins one). On any other the raw offsets are not read at all (an
#: address from another layout could point anywhere): :data:`LOOPS` holds zeros, the kernels
#: use the C library's functions, and a warning says so, as :mod:`clis_base.ros.
#: rclpy_private` does for rclpy.
CHECKED_ON = ('2.4',)


def numpy_version() -> str:
    """The installed numpy's version (its package metadata; ``np.__version__`` otherwise)."""
    try:
        return importlib.metadata.version('numpy')
    except importlib.metadata.PackageNotFoundError:   # pragma: no cover
        return np.__version__


def supported(version: str | None = None) -> bool:
    """Whether numpy ``version`` (default: the installed one) is one of :data:`CHECKED_ON`."""
    v = (version or numpy_version()).split('.')
    return '.'.join(v[:2]) in CHECKED_ON


def _loop_of(ufunc: np.ufunc, types: str) -> tuple[int, int]:
    """(inner loop function, its data) of ``ufunc`` for ``types`` (``'d->d'``), read from the
    ``PyUFuncObject`` (after ``PyObject_HEAD``: ``int nin, nout, nargs, identity``, then
    ``functions``, ``data``, ``int ntypes``)."""
    base = id(ufunc)
    head = ctypes.sizeof(ctypes.c_ssize_t) + ctypes.sizeof(ctypes.c_void_p)
    ptr = ctypes.sizeof(ctypes.c_void_p)
    functions = ctypes.c_void_p.from_address(base + head + 16).value
    data = ctypes.c_void_p.from_address(base + head + 16 + ptr).value
    ntypes = ctypes.c_int.from_address(base + head + 16 + 2 * ptr).value
    if not functions or ntypes != len(ufunc.types):
        return 0, 0
    k = ufunc.types.index(types)
    fn = ctypes.c_void_p.from_address(functions + ptr * k).value or 0
    d = (ctypes.c_void_p.from_address(data + ptr * k).value or 0) if data else 0
    return fn, d


if HAVE_NUMBA:   # pragma: no branch
    from llvmlite import ir
    from numba import types as nbtypes
    from numba.extending import intrinsic

    @intrinsic
    def _call_loop(typingctx, fn, args, dims, steps, data):  # noqa: ARG001
        """Call the ufunc inner loop at address ``fn`` (``void (char **args, npy_intp const
        *dimensions, npy_intp const *steps, void *data)``), all arguments as addresses."""
        sig = nbtypes.void(nbtypes.intp, nbtypes.intp, nbtypes.intp, nbtypes.intp,
                           nbtypes.intp)

        def codegen(context, builder, signature, a):
            i8p = ir.IntType(8).as_pointer()
            ip = context.get_value_type(nbtypes.intp).as_pointer()
            fnty = ir.FunctionType(ir.VoidType(), [i8p.as_pointer(), ip, ip, i8p])
            f = builder.inttoptr(a[0], fnty.as_pointer())
            builder.call(f, [builder.inttoptr(a[1], i8p.as_pointer()),
                             builder.inttoptr(a[2], ip), builder.inttoptr(a[3], ip),
                             builder.inttoptr(a[4], i8p)])
            return context.get_dummy_value()
        return sig, codegen

    @njit
    def exp_into(loops: np.ndarray, x: np.ndarray, out: np.ndarray, n: int) -> None:
        """``out[:n] = np.exp(x[:n])`` (contiguous float64 arrays), numpy's loop."""
        if n <= 0:
            return
        if loops[0] == 0:
            for i in range(n):
                out[i] = np.exp(x[i])
            return
        ptrs = np.empty(2, dtype=np.intp)
        ptrs[0] = x.ctypes.data
        ptrs[1] = out.ctypes.data
        dims = np.empty(1, dtype=np.intp)
        dims[0] = n
        steps = np.empty(2, dtype=np.intp)
        steps[0] = steps[1] = 8
        _call_loop(loops[0], ptrs.ctypes.data, dims.ctypes.data, steps.ctypes.data, loops[1])

    @njit
    def arctan2_into(loops: np.ndarray, y: np.ndarray, x: np.ndarray, out: np.ndarray,
                     n: int) -> None:
        """``out[:n] = np.arctan2(y[:n], x[:n])`` (contiguous float64 arrays), numpy's
        loop."""
        if n <= 0:
            return
        if loops[2] == 0:
            for i in range(n):
                out[i] = np.arctan2(y[i], x[i])
            return
        ptrs = np.empty(3, dtype=np.intp)
        ptrs[0] = y.ctypes.data
        ptrs[1] = x.ctypes.data
        ptrs[2] = out.ctypes.data
        dims = np.empty(1, dtype=np.intp)
        dims[0] = n
        steps = np.empty(3, dtype=np.intp)
        steps[0] = steps[1] = steps[2] = 8
        _call_loop(loops[2], ptrs.ctypes.data, dims.ctypes.data, steps.ctypes.data, loops[3])
else:  # pragma: no cover
    def exp_into(loops: np.ndarray, x: np.ndarray, out: np.ndarray, n: int) -> None:
        """``out[:n] = np.exp(x[:n])``."""
        out[:n] = np.exp(x[:n])

    def arctan2_into(loops: np.ndarray, y: np.ndarray, x: np.ndarray, out: np.ndarray,
                     n: int) -> None:
        """``out[:n] = np.arctan2(y[:n], x[:n])``."""
        out[:n] = np.arctan2(y[:n], x[:n])


@njit
def block_sum(a: np.ndarray, lo: int, n: int) -> float:
    """``np.sum(a[lo:lo + n])`` for ``n <= 128`` (one block of numpy's pairwise summation:
    8 partial sums; sequential from -0.0 below 8 elements)."""
    if n < 8:
        res = -0.0
        for i in range(lo, lo + n):
            res += a[i]
        return res
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    i = lo + 8
    stop = lo + n - n % 8
    while i < stop:
        r0 += a[i]
        r1 += a[i + 1]
        r2 += a[i + 2]
        r3 += a[i + 3]
        r4 += a[i + 4]
        r5 += a[i + 5]
        r6 += a[i + 6]
        r7 += a[i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < lo + n:
        res += a[i]
        i += 1
    return res


@njit
def pairwise_sum(a: np.ndarray, lo: int, n: int) -> float:
    """``np.sum(a[lo:lo + n])`` of a contiguous float64 array, in numpy's order of additions:
    its pairwise summation splits ``n > 128`` elements at ``n2 = n // 2 - (n // 2) % 8``
    and adds the sums of the two parts, blocks of at most 128 by :func:`block_sum`.

    The recursion runs on an explicit stack (numba's cache cannot hold a self-recursive
    function: loading one compiled by another process crashes)."""
    if n <= 128:
        return block_sum(a, lo, n)
    los = np.empty(64, dtype=np.int64)       # depth <= log2(n): 64 is never reached
    ns = np.empty(64, dtype=np.int64)
    left = np.empty(64)                      # sum of the left part, once known
    stage = np.empty(64, dtype=np.int64)     # 0: new, 1: left part pending, 2: right part
    sp = 0
    los[0], ns[0], stage[0] = lo, n, 0
    while True:
        if ns[sp] > 128:                     # split: the left part first
            n2 = ns[sp] // 2
            n2 -= n2 % 8
            stage[sp] = 1
            los[sp + 1], ns[sp + 1], stage[sp + 1] = los[sp], n2, 0
            sp += 1
            continue
        v = block_sum(a, los[sp], ns[sp])
        sp -= 1
        while sp >= 0 and stage[sp] == 2:    # right parts done: left + right, upwards
            v = left[sp] + v
            sp -= 1
        if sp < 0:
            return v
        left[sp] = v                         # a left part done: now its right part
        stage[sp] = 2
        n2 = ns[sp] // 2
        n2 -= n2 % 8
        los[sp + 1], ns[sp + 1], stage[sp + 1] = los[sp] + n2, ns[sp] - n2, 0
        sp += 1


def _checked_loops(version: str | None = None) -> np.ndarray:
    """The addresses ``(exp, its data, arctan2, its data)``, checked against numpy on inputs
    that cover the ranges the project's kernels feed them; zeros if anything differs, and
    without reading them when numpy ``version`` (default: the installed one) is not one the
    layout was checked on (:data:`CHECKED_ON`)."""
    zeros = np.zeros(4, dtype=np.intp)
    if not supported(version):
        warnings.warn(f'clis_base.ufunc_loops: numpy {version or numpy_version()} is not one '
                      f'of {", ".join(CHECKED_ON)} whose ufunc layout was checked; using the C '
                      "library's exp/arctan2 in the kernels (results differ from numpy's in the "
                      'last bits)', RuntimeWarning, stacklevel=2)
        return zeros
    try:
        loops = np.array((*_loop_of(np.exp, 'd->d'), *_loop_of(np.arctan2, 'dd->d')),
                         dtype=np.intp)
    except (ValueError, OSError):   # pragma: no cover
        return zeros
    if not HAVE_NUMBA or loops[0] == 0 or loops[2] == 0:
        return zeros
    rng = np.random.default_rng(0)
    x = np.concatenate([rng.uniform(-60.0, 1.0, 4000), [0.0, -0.0, -50.0, -700.0]])
    y = rng.uniform(-4.0, 4.0, x.shape[0])
    out = np.empty_like(x)
    exp_into(loops, x, out, x.shape[0])
    ok = np.array_equal(out, np.exp(x))
    arctan2_into(loops, y, x, out, x.shape[0])
    ok = ok and np.array_equal(out, np.arctan2(y, x))
    if not ok:   # pragma: no cover
        warnings.warn("clis_base.ufunc_loops: numpy's exp/arctan2 loops could not be "
                      "called from the kernels; using the C library's (results differ from "
                      "numpy's in the last bits)", RuntimeWarning, stacklevel=2)
        return zeros
    return loops


#: ``(exp loop, its data, arctan2 loop, its data)`` of this process (zeros: fall back).
LOOPS = _checked_loops()
