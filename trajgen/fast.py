"""Optional compiled evaluation of the blending spline (numba): the same arithmetic as numpy.

The numpy path (:mod:`trajgen.jet`, :mod:`trajgen.local_curves`) is the reference;
:mod:`trajgen.fast_kernel` restates it per sample for numba. It is used by
:class:`~trajgen.spline.BlendingSpline` when numba is installed (the ``fast``
extra) unless ``TRAJGEN_NUMBA=0``; numba is imported, and the kernel compiled
(cached on disk), at the first evaluation, not at ``import trajgen``. Tests check
that both paths agree.
"""

from __future__ import annotations

import importlib.util
import os

import numpy as np


def _numba_installed() -> bool:
    try:
        return importlib.util.find_spec("numba") is not None
    except (ImportError, ValueError):  # a module set to None in sys.modules
        return False


ENABLED = os.environ.get("TRAJGEN_NUMBA", "1") != "0" and _numba_installed()


def use_compiled(samples: int) -> bool:
    return ENABLED


def evaluate(spline, t: np.ndarray, seg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Compiled evaluation at times ``t`` (M,) in segments ``seg`` (M,).

    Returns ``q`` (M, 4) and the space-frame ``omega, alpha, jerk`` stacked (3, M, 3).
    """
    from .fast_kernel import evaluate as kernel

    out_q = np.empty((len(t), 4))
    out_w = np.empty((3, len(t), 3))
    table = spline._curves.row_table
    kernel(t, seg, spline.times, spline._left, spline._right, spline._blend, table, out_q, out_w)
    return out_q, out_w
