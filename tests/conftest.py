"""Shared test fixtures. MUJOCO_GL must be set before anything imports mujoco."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402
import pytest  # noqa: E402


@pytest.fixture
def rng():
    """A seeded generator: every test run draws the same numbers."""
    return np.random.default_rng(20260521)


def quintic_trajectory(amplitude_rad, duration_s, rate_hz=200.0, start_rad=(0.0, 0.0, 0.0)):
    """A rest-to-rest joint move with exact derivatives.

    Each joint follows ``start + amplitude (10 s^3 - 15 s^4 + 6 s^5)``,
    ``s = t / duration_s``: zero velocity and acceleration at both ends, peak
    speed ``1.875 amplitude / duration_s``.
    """
    from trajgen.sampling import sample_times
    from trajgen.stream import JointTrajectory

    t = sample_times(0.0, duration_s, rate_hz)
    s = (t / duration_s)[:, None]
    a = np.asarray(amplitude_rad, dtype=float)
    q = np.asarray(start_rad, dtype=float) + a * (10 * s**3 - 15 * s**4 + 6 * s**5)
    qd = a * (30 * s**2 - 60 * s**3 + 30 * s**4) / duration_s
    qdd = a * (60 * s - 180 * s**2 + 120 * s**3) / duration_s**2
    return JointTrajectory(t, q, qd, qdd, float(rate_hz))


def random_walk_keyframes(seed, n, spread, boundary):
    """Keyframes (n, 4) a random walk of rotations apart (``spread`` rad per step), at
    random increasing times shifted by up to 5 s; closed loops repeat the first."""
    from trajgen import quat as Q

    rng = np.random.default_rng(seed)
    steps = Q.exp(rng.normal(scale=spread, size=(n, 3)))
    q = steps.copy()
    for i in range(1, n):
        q[i] = Q.mul(steps[i], q[i - 1])
    if boundary == "closed":
        n = max(n, 3)
        q = np.vstack([q[: n - 1], q[:1]])
    t = np.concatenate([[0.0], np.cumsum(rng.uniform(0.1, 3.0, n - 1))])
    return q, t + rng.uniform(-5.0, 5.0)


@pytest.fixture
def answered_here(monkeypatch):
    """``answered_here(virtual)``: a ``ServoBus`` opened by name on the port of the
    lock-step ``virtual`` (as the session and the command line open it) is answered in
    this thread, as ``VirtualBus.connect`` makes it: the stream then runs on simulated
    time, and no reply or deadline waits for another thread, whatever the host's load."""
    from trajgen.drivers import bus as bus_module

    real = bus_module.ServoBus

    def answered(virtual):
        def servo_bus(port, **kwargs):
            if port == virtual.port:
                kwargs.setdefault("responder", virtual)
            return real(port, **kwargs)

        monkeypatch.setattr(bus_module, "ServoBus", servo_bus)
        return virtual

    return answered
