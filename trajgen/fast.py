"""Optional compiled evaluation of the splines (numba): the same arithmetic as numpy.

The numpy paths (:meth:`trajgen.spline.BlendingSpline._blend_derivatives`,
``SmoothSpline._space_rates``) are the reference; :mod:`trajgen.fast_kernel`
restates them per sample for numba. Tests check that both agree.

Loading numba and its cached kernel costs a second or more of start-up, which
only large evaluations win back, so by default (``TRAJGEN_NUMBA`` unset or
``auto``) the kernel is loaded for the first evaluation of at least
``LOAD_SAMPLES`` samples, and once loaded it serves every evaluation; batches
under ``PARALLEL_SAMPLES`` run on one thread (thread start-up and a busy
machine's scheduling would cost more than they save). ``TRAJGEN_NUMBA=1``
uses it for every evaluation, ``TRAJGEN_NUMBA=0`` never. ``import trajgen``
never imports numba.
"""

from __future__ import annotations

import importlib.util
import os
import sys

import numpy as np


def _numba_installed() -> bool:
    try:
        return importlib.util.find_spec("numba") is not None
    except (ImportError, ValueError):  # a module set to None in sys.modules
        return False


#: "auto", "always" or "never", from the environment variable TRAJGEN_NUMBA.
MODE = {"0": "never", "1": "always"}.get(os.environ.get("TRAJGEN_NUMBA", "auto"), "auto")
ENABLED = MODE != "never" and _numba_installed()

#: Samples in one evaluation that pay for loading numba (measured: see bench/numba_load.py).
LOAD_SAMPLES = 2_000_000
#: Samples from which the compiled kernel runs on all of numba's threads.
PARALLEL_SAMPLES = 20_000


def use_compiled(samples: int) -> bool:
    """Whether an evaluation of ``samples`` samples runs compiled."""
    if not ENABLED:
        return False
    return MODE == "always" or samples >= LOAD_SAMPLES or "trajgen.fast_kernel" in sys.modules


def evaluate(spline, t: np.ndarray, seg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Compiled evaluation of a BlendingSpline at times ``t`` (M,) in segments ``seg`` (M,).

    Returns ``q`` (M, 4) and the space-frame ``omega, alpha, jerk`` stacked (3, M, 3).
    """
    from . import fast_kernel

    return _run(
        fast_kernel.evaluate_parallel,
        fast_kernel.evaluate_serial,
        t,
        seg,
        spline.times,
        spline._inv_h,
        spline._left,
        spline._right,
        spline._blend,
        spline._curves.kernel_table,
    )


def evaluate_smooth(spline, t: np.ndarray, seg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Compiled evaluation of a SmoothSpline, as :func:`evaluate` (same returns)."""
    from . import fast_kernel

    return _run(
        fast_kernel.smooth_parallel,
        fast_kernel.smooth_serial,
        t,
        seg,
        spline.times,
        spline.tangent_coefficients,
        spline.quats,
    )


def _run(parallel, serial, t, seg, *arrays) -> tuple[np.ndarray, np.ndarray]:
    """One of a kernel pair on ``len(t)`` samples (threads from ``PARALLEL_SAMPLES``)."""
    out_q = np.empty((len(t), 4))
    out_w = np.empty((3, len(t), 3))
    (parallel if len(t) >= PARALLEL_SAMPLES else serial)(t, seg, *arrays, out_q, out_w)
    return out_q, out_w
