"""The blending spline's closed-form evaluation against its jet reference; the call cache."""

import numpy as np
import pytest

from trajgen import BlendingSpline, SmoothSpline, fast, per_sample, spline
from trajgen import derivatives as D
from trajgen import quat as Q
from trajgen.path import OrientationPath


def random_walk(rng, n, scale):
    steps = Q.exp(rng.normal(scale=scale, size=(n, 3)))
    q = steps.copy()
    for i in range(1, n):
        q[i] = Q.mul(steps[i], q[i - 1])
    return q


@pytest.fixture(autouse=True)
def numpy_only(monkeypatch):
    monkeypatch.setattr(fast, "ENABLED", False)


def reference(s, t, max_order):
    """The jet path (OrientationPath._space_rates over BlendingSpline._jet)."""
    seg, ta = s._segment(t)
    return OrientationPath._space_rates(s, ta, seg, max_order)


@pytest.mark.parametrize("boundary", ["rest", "natural", "closed"])
@pytest.mark.parametrize("local", ["auto", "circle", "parabola"])
@pytest.mark.parametrize("reparam", ["rational", "paper"])
def test_closed_form_matches_the_jet_reference(boundary, local, reparam, rng):
    for trial in range(3):
        n = int(rng.integers(3, 8))
        q = random_walk(rng, n, [0.05, 0.5, 1.2][trial]) if trial else rng.normal(size=(n, 4))
        if boundary == "closed":
            q[-1] = q[0]
        t = np.concatenate([[0.0], np.cumsum(rng.uniform(0.3, 2.0, n - 1))])
        k = int(rng.integers(1, 4))
        try:
            s = BlendingSpline(q, t, k=k, boundary=boundary, local=local, reparam=reparam)
        except ValueError:  # a reversal with local="circle"
            continue
        tt = np.concatenate([np.linspace(t[0], t[-1], 301), t, t[1:-1] + 1e-4, t[1:-1] - 1e-4])
        for order in range(4):
            q_ref, r_ref = reference(s, tt, order)
            got = s.evaluate(tt, max_order=order)
            np.testing.assert_allclose(got.q, q_ref, rtol=0, atol=1e-12)
            for a, b in zip((got.omega, got.alpha, got.jerk)[:order], r_ref, strict=True):
                np.testing.assert_allclose(a, b, rtol=0, atol=1e-9 * (1 + np.abs(b).max()))


def test_degenerate_triples_match_the_jet_reference():
    a = np.radians([[0, 0, 0], [30, 0, 0], [30, 0, 0], [0, 0, 0], [10, 5, 0], [10, 5, 0]])
    q = Q.from_pan_tilt_roll(a[:, 0], a[:, 1], a[:, 2])
    for k in (1, 2, 3):
        s = BlendingSpline(q, np.arange(6.0), k=k)
        tt = np.linspace(0, 5, 501)
        q_ref, r_ref = reference(s, tt, 3)
        got = s.evaluate(tt, max_order=3)
        np.testing.assert_allclose(got.q, q_ref, atol=1e-12)
        for a_, b in zip((got.omega, got.alpha, got.jerk), r_ref, strict=True):
            np.testing.assert_allclose(a_, b, atol=1e-9 * (1 + np.abs(b).max()))


def test_blocks_do_not_change_results(monkeypatch, rng):
    s = BlendingSpline(random_walk(rng, 9, 0.6), np.arange(9.0))
    tt = rng.uniform(0, 8, 1000)  # unsorted on purpose
    whole = s.evaluate(tt, max_order=3)
    monkeypatch.setattr(spline, "CHUNK", 7)
    blocks = s.evaluate(tt, max_order=3)
    for a, b in zip(whole[1:], blocks[1:], strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("local", ["auto", "circle", "parabola"])
def test_one_sample_gives_its_row_of_a_batch(local, rng, monkeypatch):
    # Numpy's single-sample shortcuts (floats in place of arrays) give the same bits as
    # the batch, and the per-sample Python that serves a few samples agrees with it, on
    # both sides of every series threshold (times at and next to the knots).
    s = BlendingSpline(random_walk(rng, 7, 0.5), np.arange(7.0), local=local)
    tt = np.concatenate([rng.uniform(0, 6, 40), np.arange(7.0), np.arange(1.0, 6.0) + 1e-3])
    seg, tt = s._segment(tt)
    q, rates = s._space_rates(tt, seg, 3)
    for python_samples, atol in ((0, 0.0), (fast.PYTHON_SAMPLES, 1e-12)):
        monkeypatch.setattr(fast, "PYTHON_SAMPLES", python_samples)
        for i in range(len(tt)):
            q1, rates1 = s._space_rates(tt[i : i + 1], seg[i : i + 1], 3)
            np.testing.assert_allclose(q1[0], q[i], rtol=0, atol=atol)
            for a, b in zip(rates1, rates, strict=True):
                np.testing.assert_allclose(a[0], b[i], rtol=0, atol=atol * (1 + np.abs(b).max()))


def test_few_samples_run_in_python_and_agree_with_numpy(rng, monkeypatch):
    # Up to PYTHON_SAMPLES samples run trajgen.per_sample in Python (no numba here).
    q, t = random_walk(rng, 9, 0.6), np.cumsum(rng.uniform(0.5, 1.5, 9))
    calls = []
    monkeypatch.setattr(per_sample, "evaluate_range", spy(per_sample.evaluate_range, calls))
    monkeypatch.setattr(per_sample, "smooth_range", spy(per_sample.smooth_range, calls))
    for s in (BlendingSpline(q, t, k=3), SmoothSpline(q, t)):
        tt = np.concatenate([t, t[:-1] + 1e-4, rng.uniform(t[0], t[-1], 30)])
        reference = s.evaluate(tt, max_order=3)  # numpy: more than PYTHON_SAMPLES
        for i in range(0, len(tt), fast.PYTHON_SAMPLES):
            few = s.evaluate(tt[i : i + fast.PYTHON_SAMPLES], max_order=3)
            for a, b in zip(few, reference, strict=True):
                b = b[i : i + fast.PYTHON_SAMPLES]
                np.testing.assert_allclose(a, b, rtol=0, atol=1e-12 * (1 + np.abs(b).max()))
    assert len(calls) == 2 * -(-len(tt) // fast.PYTHON_SAMPLES)


def spy(fn, calls):
    def wrapped(*args):
        calls.append(args[:2])
        return fn(*args)

    return wrapped


@pytest.mark.parametrize("f", [0.0, 0.3, 1.0])
def test_slerp_weight_branches_agree_at_the_threshold(f):
    from trajgen.path import run_steps

    # The series and the closed form of the slerp weights on both sides of SERIES_BELOW.
    z = np.array([0.5, 0.9, 1.0, 1.1, 2.0]) * D.SERIES_BELOW
    zl = [z, 0.3 * np.ones(5), -0.7 * np.ones(5), 0.2 * np.ones(5)]
    fl = [np.full(5, f), 0.8 * np.ones(5), -1.5 * np.ones(5), 4.0 * np.ones(5)]
    series = run_steps(D._slerp_weights_series(zl, fl, 3))
    closed = run_steps(D._slerp_weights_closed(zl, fl, 3))
    for a, b in zip(series, closed, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-12)


def test_call_cache_shares_the_scipy_pattern(monkeypatch, rng):
    s = BlendingSpline(random_walk(rng, 6, 0.5), np.arange(6.0))
    calls = []
    evaluate = s.evaluate

    def counting(t, *, max_order=2, frame="space"):
        calls.append(max_order)
        return evaluate(t, max_order=max_order, frame=frame)

    monkeypatch.setattr(s, "evaluate", counting)
    t = np.linspace(0, 5, 101)
    q, w, a = s(t), s(t, 1), s(t, 2)
    assert calls == [0, 2]  # the orientation, then the rates together
    ref = evaluate(t, max_order=2)
    np.testing.assert_allclose(q, ref.q, rtol=0, atol=1e-15)  # order 0 has its own forms
    np.testing.assert_array_equal(w, ref.omega)
    np.testing.assert_array_equal(a, ref.alpha)
    # Results are copies: changing one does not change the next call's.
    w[:] = 0.0
    np.testing.assert_array_equal(s(t, 1), ref.omega)
    assert calls == [0, 2]
    # Other times, another frame or a higher order evaluate again.
    s(t[:50], 1)
    s(t[:50], 1, frame="body")
    s(t[:50], 3, frame="body")
    assert calls == [0, 2, 1, 1, 3]
    t2 = t.copy()
    t2[7] += 1e-9
    s(t2, 1)
    assert calls[-1] == 1


@pytest.mark.parametrize("local", ["auto", "circle", "parabola"])
@pytest.mark.parametrize("reparam", ["rational", "paper"])
def test_vectorised_construction_matches_one_triple_at_a_time(local, reparam, rng):
    from trajgen.local_curves import LocalCurves, NoCircleError, build_curve, build_curves

    n = 60
    q = random_walk(rng, n, 0.6)
    q[10] = q[11]  # repeated keyframes: geodesic and held-point triples
    q[20] = q[21] = q[22]
    q[31] = q[29]  # a reversal (refused by circles)
    signs = np.where(np.cumsum(np.einsum("ij,ij->i", q[1:], q[:-1]) < 0) % 2, -1.0, 1.0)
    q[1:] *= signs[:, None]
    t = np.cumsum(rng.uniform(0.2, 2.0, n))
    triples = np.stack([q[:-2], q[1:-1], q[2:]], axis=1)
    times = np.stack([t[:-2], t[1:-1], t[2:]], axis=1)
    options = {"k": 2, "local": local, "reparam": reparam}
    if local == "circle":
        with pytest.raises(NoCircleError) as error:
            build_curves(triples, times, **options)
        assert error.value.index == 29  # the triple centred on keyframe 30
        keep = np.arange(len(triples)) != 29
        triples, times = triples[keep], times[keep]
    fast = build_curves(triples, times, **options)
    rows = [build_curve(a, b, **options) for a, b in zip(triples, times, strict=True)]
    slow = LocalCurves.from_rows(rows)
    np.testing.assert_array_equal(fast.kind, slow.kind)
    np.testing.assert_array_equal(fast.g_kind, slow.g_kind)
    for name in ("q", "centre", "radius", "e1", "e2", "a3", "g_coef", "A", "B", "rise", "power"):
        np.testing.assert_allclose(getattr(fast, name), getattr(slow, name), rtol=1e-9, atol=1e-11)
    # The same spline either way.
    ids = np.tile(np.arange(len(triples)), 20)
    tt = times[ids, 0] + rng.uniform(0, 1, len(ids)) * (times[ids, 2] - times[ids, 0])
    for a, b in zip(fast.derivatives(ids, tt, 3), slow.derivatives(ids, tt, 3), strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-9 * (1 + np.abs(b).max()))


def test_evaluation_steps_give_evaluate(rng):
    from trajgen.path import run_steps

    s = BlendingSpline(random_walk(rng, 7, 0.7), np.arange(7.0), k=3)
    t = np.linspace(0, 6, 40)
    steps = s.evaluation_steps(t, max_order=3)
    count = 0
    while True:
        try:
            next(steps)
            count += 1
        except StopIteration as done:
            got = done.value
            break
    assert count >= 5  # the work comes in several parts
    ref = s.evaluate(t, max_order=3)
    for a, b in zip(got, ref, strict=True):
        np.testing.assert_array_equal(a, b)
    # Any path has them (in one step by default).
    from trajgen.compare import Squad

    sq = Squad(random_walk(rng, 5, 0.4), np.arange(5.0))
    tq = np.linspace(0, 4, 30)
    got = run_steps(sq.evaluation_steps(tq, max_order=1))
    np.testing.assert_array_equal(got.omega, sq.evaluate(tq, max_order=1).omega)


def test_stream_of_a_blending_spline_equals_the_plan(rng):
    from trajgen.stream import BLOCK_FRAMES, plan_joint_trajectory, stream_frames

    a = np.radians([[0, 0, 0], [40, 10, 5], [80, -20, 0], [30, 15, -10], [0, 0, 0]])
    s = BlendingSpline(Q.from_pan_tilt_roll(a[:, 0], a[:, 1], a[:, 2]), [0, 0.3, 0.7, 1.1, 1.5])
    plan = plan_joint_trajectory(s, 200.0)
    frames = list(stream_frames(s, 200.0))
    assert len(frames) == len(plan) > 3 * BLOCK_FRAMES
    for name in ("q", "qd", "qdd"):
        np.testing.assert_allclose(
            [getattr(f, name) for f in frames], getattr(plan, name), atol=1e-12
        )
