"""The optional compiled path (numba) agrees with the numpy reference; trajgen works without it."""

import os
import subprocess
import sys

import numpy as np
import pytest
from conftest import random_walk_keyframes

from trajgen import BlendingSpline, SmoothSpline, fast
from trajgen import quat as Q

pytest.importorskip("numba")


@pytest.mark.parametrize("local", ["circle", "parabola", "auto"])
@pytest.mark.parametrize("reparam", ["paper", "rational"])
@pytest.mark.parametrize("boundary", ["rest", "natural", "closed"])
def test_compiled_path_matches_numpy(local, reparam, boundary, monkeypatch):
    q, t = random_walk_keyframes(7, 7, 0.3, boundary)
    if boundary == "closed" and local == "circle":
        local = "parabola"  # no circle on the seam reversal
    s = BlendingSpline(q, t, k=3, local=local, reparam=reparam, boundary=boundary)
    tt = np.concatenate([np.linspace(t[0], t[-1], 999), t])
    compiled, reference = compiled_and_reference(s, tt, monkeypatch)
    for a, b in zip(compiled[1:], reference[1:], strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-9 * (1 + np.abs(b).max()))


def compiled_and_reference(spline, t, monkeypatch):
    """``spline.evaluate(t, max_order=3)`` compiled (after checking that one and many
    threads agree bit for bit) and with numpy."""
    monkeypatch.setattr(fast, "ENABLED", True)
    monkeypatch.setattr(fast, "MODE", "always")
    compiled = spline.evaluate(t, max_order=3)
    monkeypatch.setattr(fast, "PARALLEL_SAMPLES", 1)  # the multi-threaded kernel too
    parallel = spline.evaluate(t, max_order=3)
    monkeypatch.setattr(fast, "ENABLED", False)
    for a, b in zip(compiled, parallel, strict=True):
        np.testing.assert_array_equal(a, b)
    return compiled, spline.evaluate(t, max_order=3)


@pytest.mark.parametrize("boundary", ["rest", "natural", "closed"])
def test_compiled_smooth_spline_matches_numpy(boundary, monkeypatch):
    """SmoothSpline's kernel against its numpy closed form, both series branches
    (the keyframes themselves, where r = 0, take the series)."""
    q, t = random_walk_keyframes(11, 7, 0.6, boundary)
    s = SmoothSpline(q, t, boundary=boundary)
    tt = np.concatenate([np.linspace(t[0], t[-1], 999), t, t[:-1] + 1e-4])
    compiled, reference = compiled_and_reference(s, tt, monkeypatch)
    for a, b in zip(compiled, reference, strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12 * (1 + np.abs(b).max()))


def test_degenerate_keys_match(monkeypatch):
    a = np.radians([[0, 0, 0], [30, 0, 0], [30, 0, 0], [0, 0, 0], [10, 5, 0]])
    q = Q.from_pan_tilt_roll(a[:, 0], a[:, 1], a[:, 2])
    s = BlendingSpline(q, np.arange(5.0), k=2)
    tt = np.linspace(0, 4, 401)
    monkeypatch.setattr(fast, "ENABLED", True)
    monkeypatch.setattr(fast, "MODE", "always")
    compiled = s.evaluate(tt, max_order=3, frame="body")
    monkeypatch.setattr(fast, "ENABLED", False)
    reference = s.evaluate(tt, max_order=3, frame="body")
    for x, y in zip(compiled[1:], reference[1:], strict=True):
        np.testing.assert_allclose(x, y, atol=1e-9)


def test_trajgen_imports_and_runs_without_numba():
    code = (
        "import sys; sys.modules['numba'] = None\n"
        "import numpy as np, trajgen\n"
        "from trajgen import fast\n"
        "assert not fast.ENABLED\n"
        "s = trajgen.BlendingSpline([[1, 0, 0, 0], [0, 0, 0, 1]], [0.0, 1.0])\n"
        "print(s(0.5, 1))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr


def test_numba_is_loaded_only_for_large_evaluations():
    # In a fresh process: small evaluations stay on numpy and never import numba; one of
    # LOAD_SAMPLES samples loads the kernel, which then serves small ones too.
    code = (
        "import sys, numpy as np, trajgen\n"
        "from trajgen import fast\n"
        "assert fast.ENABLED and fast.MODE == 'auto'\n"
        "fast.LOAD_SAMPLES = 5000\n"
        "s = trajgen.BlendingSpline([[1, 0, 0, 0], [0.8, 0.6, 0, 0], [0, 0, 0, 1]], [0, 1, 2])\n"
        "small = s.evaluate(np.linspace(0, 2, 4999))\n"
        "assert 'numba' not in sys.modules and not fast.use_compiled(4999)\n"
        "s.evaluate(np.linspace(0, 2, 5000))\n"
        "assert 'trajgen.fast_kernel' in sys.modules and fast.use_compiled(10)\n"
        "again = s.evaluate(np.linspace(0, 2, 4999))\n"
        "assert np.abs(again.alpha - small.alpha).max() < 1e-9\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "TRAJGEN_NUMBA"}
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert proc.returncode == 0, proc.stderr


@pytest.mark.parametrize(("value", "mode"), [("0", "never"), ("1", "always"), ("auto", "auto")])
def test_environment_selects_the_mode(value, mode):
    code = "from trajgen import fast; print(fast.MODE, fast.use_compiled(10**9))"
    env = dict(os.environ, TRAJGEN_NUMBA=value)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert proc.stdout.split() == [mode, str(mode != "never")], proc.stderr
