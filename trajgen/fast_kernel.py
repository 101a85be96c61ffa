"""The numba kernel behind :mod:`trajgen.fast` (imported only when it is used).

Compiles :mod:`trajgen.per_sample`: every function there is registered with
numba (those in ``per_sample.INLINE`` inlined into their callers), and the
entry points below loop over the samples, on one thread or across numba's.

numba caches the compiled kernel keyed on this file alone: after editing
``per_sample.py`` in a source checkout, touch this file (``make test``
and ``make bench`` do).
"""

from __future__ import annotations

import warnings

import numba
from numba.core.errors import NumbaIRAssumptionWarning
from numba.extending import register_jitable

from . import per_sample as P

for _name, _fn in vars(P).items():
    if callable(_fn) and getattr(_fn, "__module__", None) == P.__name__:
        inline = "always" if _name in P.INLINE else "never"
        register_jitable(error_model="numpy", inline=inline)(_fn)

# numba's internal "pedantic check" warns about a variable's scope in curve's
# branches once inlined here; the compiled results are tested against numpy.
warnings.filterwarnings("ignore", category=NumbaIRAssumptionWarning, module=r".*fast_kernel$")

njit = numba.njit(cache=True, error_model="numpy")
parallel = numba.njit(cache=True, parallel=True, error_model="numpy")


@njit
def evaluate_serial(t, seg, times, inv_h, left, right, blend, tab, out_q, out_w):
    P.evaluate_range(0, len(t), t, seg, times, inv_h, left, right, blend, tab, out_q, out_w)


@parallel
def evaluate_parallel(t, seg, times, inv_h, left, right, blend, tab, out_q, out_w):
    # Ranges of samples across the threads (the per-sample code stays out of the parfor:
    # inlined there, it confused numba's array analysis).
    n, parts = len(t), 64
    for k in numba.prange(parts):
        a, b = k * n // parts, (k + 1) * n // parts
        P.evaluate_range(a, b, t, seg, times, inv_h, left, right, blend, tab, out_q, out_w)


@njit
def smooth_serial(t, seg, times, poly, quats, out_q, out_w):
    P.smooth_range(0, len(t), t, seg, times, poly, quats, out_q, out_w)


@parallel
def smooth_parallel(t, seg, times, poly, quats, out_q, out_w):
    n, parts = len(t), 64
    for k in numba.prange(parts):
        P.smooth_range(
            k * n // parts, (k + 1) * n // parts, t, seg, times, poly, quats, out_q, out_w
        )
