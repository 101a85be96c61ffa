"""Evaluation one sample at a time: compiled (numba, optional), or in Python for a few samples.

The numpy paths (:meth:`trajgen.spline.BlendingSpline._blend_steps`,
``SmoothSpline._space_rates``) are the reference; :mod:`trajgen.per_sample`
restates them per sample, which :mod:`trajgen.fast_kernel` compiles with numba.
Tests check that all agree. Evaluations of at most ``PYTHON_SAMPLES`` samples
run :mod:`trajgen.per_sample` as plain Python where the kernel is not loaded:
numpy's fixed cost per call is larger there.

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

from . import per_sample


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
#: Most samples evaluated in plain Python (a blending-spline sample costs 75 us there,
#: numpy's evaluation about 500 us for one sample and 600 us for 16; quiet machine).
PYTHON_SAMPLES = 4


def use_compiled(samples: int) -> bool:
    """Whether an evaluation of ``samples`` samples runs compiled."""
    if not ENABLED:
        return False
    return MODE == "always" or samples >= LOAD_SAMPLES or "trajgen.fast_kernel" in sys.modules


def samplewise(samples: int) -> bool:
    """Whether an evaluation of ``samples`` samples runs one sample at a time
    (:func:`evaluate`): compiled, or in Python for a few."""
    return 0 < samples <= PYTHON_SAMPLES or use_compiled(samples)


def evaluate(spline, t: np.ndarray, seg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A BlendingSpline at times ``t`` (M,) in segments ``seg`` (M,), one sample at a time.

    Returns ``q`` (M, 4) and the space-frame ``omega, alpha, jerk`` stacked (3, M, 3).
    """
    return _run(
        "evaluate",
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
    """A SmoothSpline, as :func:`evaluate` (same returns)."""
    return _run(
        "smooth",
        t,
        seg,
        spline.times,
        spline.tangent_coefficients,
        spline.quats,
    )


def _run(kernel: str, t, seg, *arrays) -> tuple[np.ndarray, np.ndarray]:
    """Kernel ``kernel`` ("evaluate" or "smooth") on ``len(t)`` samples: compiled where
    :func:`use_compiled` says (on numba's threads from ``PARALLEL_SAMPLES``), else in Python."""
    out_q = np.empty((len(t), 4))
    out_w = np.empty((3, len(t), 3))
    if use_compiled(len(t)):
        from . import fast_kernel

        threads = "parallel" if len(t) >= PARALLEL_SAMPLES else "serial"
        getattr(fast_kernel, f"{kernel}_{threads}")(t, seg, *arrays, out_q, out_w)
    else:
        getattr(per_sample, f"{kernel}_range")(0, len(t), t, seg, *arrays, out_q, out_w)
    return out_q, out_w
