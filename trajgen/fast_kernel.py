"""The numba kernel behind :mod:`trajgen.fast` (imported only when it is used).

Compiles :mod:`trajgen.per_sample`: each function there is compiled as a numba
function (those in ``per_sample.INLINE`` inlined into their callers) that calls
the compiled versions of the others, and the entry points below loop over the
samples, on one thread or across numba's.

numba caches the compiled kernel keyed on this file alone: after editing
``per_sample.py`` in a source checkout, touch this file (``make test``
and ``make bench`` do).
"""

from __future__ import annotations

import types

import numba

from . import per_sample as P


def _compiled(module: types.ModuleType) -> dict:
    """The module's functions compiled, by name. Each is compiled from a copy whose
    globals name the compiled functions, so that they call one another compiled."""
    namespace = dict(vars(module))
    for name, fn in vars(module).items():
        if isinstance(fn, types.FunctionType) and fn.__module__ == module.__name__:
            copy = types.FunctionType(fn.__code__, namespace, name, fn.__defaults__)
            inline = "always" if name in module.INLINE else "never"
            namespace[name] = numba.njit(error_model="numpy", inline=inline)(copy)
    return namespace


_K = _compiled(P)
evaluate_range, smooth_range = _K["evaluate_range"], _K["smooth_range"]
njit = numba.njit(cache=True, error_model="numpy")
parallel = numba.njit(cache=True, parallel=True, error_model="numpy")


@njit
def evaluate_serial(t, seg, times, inv_h, left, right, blend, tab, out_q, out_w):
    evaluate_range(0, len(t), t, seg, times, inv_h, left, right, blend, tab, out_q, out_w)


@parallel
def evaluate_parallel(t, seg, times, inv_h, left, right, blend, tab, out_q, out_w):
    # Ranges of samples across the threads (the per-sample code stays out of the parfor:
    # inlined there, it confused numba's array analysis).
    n, parts = len(t), 64
    for k in numba.prange(parts):
        a, b = k * n // parts, (k + 1) * n // parts
        evaluate_range(a, b, t, seg, times, inv_h, left, right, blend, tab, out_q, out_w)


@njit
def smooth_serial(t, seg, times, poly, quats, out_q, out_w):
    smooth_range(0, len(t), t, seg, times, poly, quats, out_q, out_w)


@parallel
def smooth_parallel(t, seg, times, poly, quats, out_q, out_w):
    n, parts = len(t), 64
    for k in numba.prange(parts):
        smooth_range(k * n // parts, (k + 1) * n // parts, t, seg, times, poly, quats, out_q, out_w)
