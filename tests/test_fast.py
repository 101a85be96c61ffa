"""The optional compiled path (numba) agrees with the numpy reference; trajgen works without it."""

import subprocess
import sys

import numpy as np
import pytest

from trajgen import BlendingSpline, fast
from trajgen import quat as Q

pytest.importorskip("numba")


@pytest.mark.parametrize("local", ["circle", "parabola", "auto"])
@pytest.mark.parametrize("reparam", ["paper", "rational"])
@pytest.mark.parametrize("boundary", ["rest", "natural", "closed"])
def test_compiled_path_matches_numpy(local, reparam, boundary, monkeypatch):
    rng = np.random.default_rng(7)
    steps = Q.exp(rng.normal(scale=0.3, size=(7, 3)))
    q = steps.copy()
    for i in range(1, len(q)):
        q[i] = Q.mul(steps[i], q[i - 1])
    if boundary == "closed":
        q[-1] = q[0]
        local = "parabola" if local == "circle" else local  # no circle on the seam reversal
    t = np.concatenate([[0.0], np.cumsum(rng.uniform(0.4, 1.6, len(q) - 1))])
    s = BlendingSpline(q, t, k=3, local=local, reparam=reparam, boundary=boundary)
    tt = np.concatenate([np.linspace(t[0], t[-1], 999), t])
    monkeypatch.setattr(fast, "ENABLED", True)
    compiled = s.evaluate(tt, max_order=3)
    monkeypatch.setattr(fast, "ENABLED", False)
    reference = s.evaluate(tt, max_order=3)
    for a, b in zip(compiled[1:], reference[1:], strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-9 * (1 + np.abs(b).max()))


def test_degenerate_keys_match(monkeypatch):
    a = np.radians([[0, 0, 0], [30, 0, 0], [30, 0, 0], [0, 0, 0], [10, 5, 0]])
    q = Q.from_pan_tilt_roll(a[:, 0], a[:, 1], a[:, 2])
    s = BlendingSpline(q, np.arange(5.0), k=2)
    tt = np.linspace(0, 4, 401)
    monkeypatch.setattr(fast, "ENABLED", True)
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
