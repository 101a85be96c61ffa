"""OnlineSpline: random sequences of extend / retarget at random times.

After every change at ``at``: the past is unchanged bit for bit, the path is C^k
across the change (exact one-sided jets, and a public-API check that separates
a jump from a slope), every keyframe still ahead is hit, and it rests at the end.
"""

import threading

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trajgen import quat as Q
from trajgen.online import MIN_LEAD_S, ChangeTooLate, OnlineSpline

DEG = np.pi / 180


def random_quats(rng, n, spread_deg=60.0):
    a = rng.uniform(-spread_deg, spread_deg, (3, n)) * DEG
    return Q.from_pan_tilt_roll(*a)


def jump_estimate(s, t, order):
    """Jump of derivative ``order`` across ``t``, a slope extrapolated away.

    ``|f(t + d) - f(t - d)|`` shrinks with ``d`` for a continuous ``f`` and tends to
    the jump otherwise; from two steps the linear part is removed.
    """
    d1, d2 = 1e-6, 1e-7
    g1 = np.linalg.norm(s(t + d1, order) - s(t - d1, order))
    g2 = np.linalg.norm(s(t + d2, order) - s(t - d2, order))
    return abs(g2 - (g1 - g2) * d2 / (d1 - d2))


def one_sided_jets(before, after, s_splice, k):
    """Taylor coefficients (0..k) at the splice from the old path (left) and the new
    piece (right), by each side's own formula: exact, no step."""
    t = np.array([s_splice])
    left = before._jet(t, before._segment(t)[0], k).c[..., 0]
    right = after.pieces[-1].jet(t, k).c[..., 0]
    return left, right


class Model:
    """What the keyframes ahead should be: extend keeps them, retarget drops them."""

    def __init__(self, q0, t0):
        self.keys = [(t0, q0)]

    def change(self, mode, quats, times, at):
        if mode == "retarget":
            self.keys = [kv for kv in self.keys if kv[0] <= at]
        self.keys += list(zip(times, quats, strict=True))


def apply_and_check(s, model, mode, quats, times, at, rng):
    """Make one change and check everything promised about it."""
    k = s.k
    past = np.sort(np.concatenate([rng.uniform(s.t_start, at, 20), [at]]))
    old = [s(past, order) for order in range(4)]
    _, before = s.snapshot()
    getattr(s, mode)(quats, times, at=at)
    model.change(mode, quats, times, at)
    _, after = s.snapshot()

    # Past unchanged, bit for bit (where the path is still kept).
    kept = past > s.t_start
    for order in range(4):
        np.testing.assert_array_equal(s(past[kept], order), old[order][kept])

    # C^k across the splice: exact jets from both sides.
    splice = after.pieces[-1].start
    left, right = one_sided_jets(before, after, splice, k)
    scale = 1.0 + np.abs(left).max(axis=1, keepdims=True)
    np.testing.assert_allclose(right / scale, left / scale, rtol=0, atol=1e-9)
    # ... and where a splice hands over to the spline's blends or to rest (its keyframe).
    piece = after.pieces[-1]
    if piece.splice is not None:
        t1 = piece.splice.times[1:2]
        left = piece.splice._jet(t1, None, k).c[..., 0]
        right = piece.jet(t1, k).c[..., 0]  # the blends' segment 1, or the hold
        scale = 1.0 + np.abs(left).max(axis=1, keepdims=True)
        np.testing.assert_allclose(right / scale, left / scale, rtol=0, atol=1e-9)
    # ... and through the public API: no jump in derivatives 0..k.
    for order in range(k + 1 if splice - 1e-6 > s.t_start else 0):
        size = 1.0 + np.linalg.norm(s(splice, order))
        assert jump_estimate(s, splice, order) < 1e-6 * size, (mode, order)

    check_frames(after)

    # Every keyframe ahead is passed at its time.
    ahead = [(t, q) for t, q in model.keys if t > at]
    for t, q in ahead:
        assert Q.distance(s(t), q) < 1e-9
    assert s.t_end == pytest.approx(ahead[-1][0] if ahead else s.t_end)


def check_frames(path, rate_hz=97.0):
    """Per stream frame (what ``stream_frames`` evaluates, ``path.frames``) the path equals
    its vectorised evaluation, on a stream grid and at every boundary exactly."""
    t0 = path.t_start
    grid = t0 + np.arange(int((path.t_end + 0.3 - t0) * rate_hz)) / rate_hz
    bounds = [path.starts, path.times]
    bounds += [p.splice.times for p in path.pieces if p.splice is not None]
    bounds += [p.spline.times for p in path.pieces if p.spline is not None]
    bounds = np.concatenate(bounds)
    t = np.sort(np.concatenate([grid, bounds[bounds >= t0]]))
    frames = path.frames(t0, rate_hz)
    got = [frames(x) for x in t.tolist()]
    ref = path.evaluate(t, max_order=2)
    for i, want in enumerate((ref.q, ref.omega, ref.alpha)):
        values = np.array([g[i] for g in got])
        np.testing.assert_allclose(values, want, rtol=0, atol=1e-11 * (1 + np.abs(want).max()))


def check_rest_at_the_end(s, model):
    t_last, q_last = model.keys[-1]
    assert s.t_end == t_last
    for t in (t_last, t_last + 0.3, t_last + 3600.0):
        assert Q.distance(s(t), q_last) < 1e-9
        for order in range(1, s.k + 1):
            np.testing.assert_allclose(s(t, order), 0.0, atol=1e-8)


def run_sequence(rng, steps, k):
    """Apply ``steps`` (mode, dt, lead, n) to a fresh spline, checking after each."""
    q0 = random_quats(rng, 1)[0]
    s = OnlineSpline(q0, 0.0, k=k)
    model = Model(q0, 0.0)
    at = 0.0
    for mode, dt, lead, n in steps:
        at += dt
        first = at + lead
        if mode == "extend":
            first = max(first, s.t_end + rng.uniform(0.1, 0.6))
        times = first + np.concatenate([[0.0], np.cumsum(rng.uniform(0.2, 0.9, n - 1))])
        apply_and_check(s, model, mode, random_quats(rng, n), times, at, rng)
    check_rest_at_the_end(s, model)
    return s


@pytest.mark.parametrize("k", [1, 2, 3])
def test_extend_right_before_the_last_keyframe(rng, k):
    """Extends when the one keyframe ahead is closer than the minimum lead: the new part
    starts from rest there; a second extend then splices at that rest start."""
    q0 = random_quats(rng, 1)[0]
    s, model = OnlineSpline(q0, k=k), Model(q0, 0.0)
    apply_and_check(s, model, "extend", random_quats(rng, 1), [1.0], 0.0, rng)
    apply_and_check(s, model, "extend", random_quats(rng, 1), [1.5], 0.9, rng)  # deferred
    assert s.pieces == 2 and s._plan.pieces[-1].start == 1.0
    apply_and_check(s, model, "extend", random_quats(rng, 2), [2.0, 2.6], 0.95, rng)
    assert s._plan.pieces[-1].start == 1.0  # spliced at the rest start, both ahead kept
    apply_and_check(s, model, "retarget", random_quats(rng, 1), [2.2], 1.7, rng)
    check_rest_at_the_end(s, model)


STEP = st.tuples(
    st.sampled_from(["extend", "retarget"]),
    st.floats(0.0, 0.8),  # time from the previous change to this one (s)
    st.floats(MIN_LEAD_S, 1.0),  # lead of the first new keyframe (s)
    st.integers(1, 4),  # new keyframes
)


@settings(derandomize=True, max_examples=25, deadline=None)
@given(steps=st.lists(STEP, min_size=1, max_size=6), k=st.integers(1, 3), seed=st.integers(0, 99))
def test_random_changes_hypothesis(steps, k, seed):
    run_sequence(np.random.default_rng(seed), steps, k)


@pytest.mark.parametrize("k", [1, 2, 3])
def test_random_changes_seeded(rng, k):
    for _ in range(4):
        steps = [
            (
                str(rng.choice(["extend", "retarget"])),
                float(rng.uniform(0, 0.6)),
                float(rng.uniform(MIN_LEAD_S, 1.0)),
                int(rng.integers(1, 4)),
            )
            for _ in range(8)
        ]
        run_sequence(rng, steps, k)


def test_fast_changes_do_not_drift(rng):
    """A change every 50 ms at k = 3 (the case that diverged when splices matched only
    order k): the path stays finite and bounded."""
    s = OnlineSpline([1, 0, 0, 0], k=3)
    at = 0.0
    for i in range(60):
        at += 0.05
        mode = "extend" if i % 2 else "retarget"
        first = max(at + MIN_LEAD_S, s.t_end + 0.1) if mode == "extend" else at + 0.3
        getattr(s, mode)(random_quats(rng, 1, 20.0), [first], at=at)
    t = np.linspace(s.t_start, s.t_end, 500)
    assert np.isfinite(s(t, 3)).all()
    assert np.abs(s(t, 1)).max() < 20.0


def test_extend_with_keyframes_ahead_is_the_offline_spline(rng):
    """Extending splices at the second-to-last keyframe ahead: from there on the path
    is the spline through all the keyframes (locality of the blend)."""
    from trajgen.spline import BlendingSpline

    q = random_quats(rng, 6)
    t = np.array([0.0, 1.0, 2.0, 3.0, 4.0, 5.0])
    s = OnlineSpline(q[0], 0.0)
    s.extend(q[1:4], t[1:4], at=0.0)
    s.extend(q[4:], t[4:], at=1.5)
    offline = BlendingSpline(q, t)
    tt = np.linspace(2.0, 5.0, 50)
    np.testing.assert_allclose(s(tt, 2), offline(tt, 2), atol=1e-12)
    np.testing.assert_allclose(np.abs((s(tt) * offline(tt)).sum(-1)), 1.0, atol=1e-14)


def test_memory_is_bounded_on_a_long_stream(rng):
    s = OnlineSpline([1, 0, 0, 0])
    at = 0.0
    for i in range(300):
        at += 0.25
        if i % 3:
            s.extend(random_quats(rng, 1, 30.0), [max(at + 0.3, s.t_end + 0.3)], at=at)
        else:
            s.retarget(random_quats(rng, 2, 30.0), [at + 0.4, at + 0.8], at=at)
        assert s.pieces <= 3
        assert len(s.times) <= 8
    assert s.t_start > at - 2.0
    with pytest.raises(ValueError, match="before the path's kept range"):
        s(0.0)


def test_rotation_input_and_body_frame(rng):
    Rotation = pytest.importorskip("scipy.spatial.transform").Rotation
    q = random_quats(rng, 3)
    r = Rotation.from_quat(q[:, [1, 2, 3, 0]])
    a = OnlineSpline(r[0])
    b = OnlineSpline(q[0])
    a.retarget(r[1:], [0.5, 1.2], at=0.0)
    b.retarget(q[1:], [0.5, 1.2], at=0.0)
    t = np.linspace(0, 1.5, 7)
    np.testing.assert_array_equal(a(t, 2), b(t, 2))
    # Body-frame rate is the space-frame rate rotated into the body.
    np.testing.assert_allclose(a(t, 1, frame="body"), Q.rotate(Q.conj(a(t)), a(t, 1)), atol=1e-12)


def test_errors():
    s = OnlineSpline([1, 0, 0, 0])
    q = Q.from_pan_tilt_roll(0.3, 0.0, 0.0)[None]
    with pytest.raises(ValueError, match=r"at least 0.2 s after it"):
        s.retarget(q, [0.1], at=0.0)
    with pytest.raises(ValueError, match=r"Expected `quats` to have shape \(N, 4\)"):
        s.retarget([1, 0, 0], [0.5], at=0.0)
    with pytest.raises(ValueError, match="strictly increasing"):
        s.retarget(np.vstack([q, q]), [0.5, 0.5], at=0.0)
    s.retarget(q, [1.0], at=0.2)
    with pytest.raises(ValueError, match="before the previous change"):
        s.retarget(q, [1.5], at=0.1)
    with pytest.raises(ValueError, match="must come after the last keyframe kept"):
        s.extend(q, [0.9], at=0.3)
    with pytest.raises(TypeError, match="`at` to be a finite number"):
        s.extend(q, [2.0], at="now")
    with pytest.raises(ValueError, match=r"`k` to be an integer in 1..3"):
        OnlineSpline([1, 0, 0, 0], k=4)
    with pytest.raises(ValueError, match="`q0` to be one quaternion"):
        OnlineSpline([[1, 0, 0, 0], [1, 0, 0, 0]])
    with pytest.raises(ValueError, match="min_lead_s"):
        OnlineSpline([1, 0, 0, 0], min_lead_s=0.05)
    s.close()
    with pytest.raises(ValueError, match="closed"):
        s.extend(q, [3.0], at=0.5)


def test_commit_refuses_changes_before_a_streamed_time():
    s = OnlineSpline([1, 0, 0, 0])
    q = Q.from_pan_tilt_roll(0.3, 0.0, 0.0)[None]
    version, _ = s.snapshot()
    assert s.commit(0.5, version)
    with pytest.raises(ChangeTooLate, match="before the streamed time 0.5"):
        s.retarget(q, [1.0], at=0.4)
    s.retarget(q, [1.0], at=0.5)
    assert not s.commit(0.6, version)  # evaluated before the change: evaluate again
    assert s.commit(0.6, s.version)


def test_check_rejects_and_keeps_the_path():
    s = OnlineSpline([1, 0, 0, 0])
    q = Q.from_pan_tilt_roll(0.3, 0.0, 0.0)[None]

    def refuse(path):
        assert path.t_start <= 0.0 and path.t_end == 1.0
        raise ValueError("no")

    with pytest.raises(ValueError, match="no"):
        s.retarget(q, [1.0], at=0.0, check=refuse)
    assert s.version == 0 and s.t_end == 0.0


def test_changes_from_another_thread_are_atomic(rng):
    """A reader sees each evaluation wholly before or wholly after a change."""
    s = OnlineSpline([1, 0, 0, 0])
    targets = random_quats(rng, 40, 40.0)
    errors = []

    def writer():
        for i, q in enumerate(targets):
            s.retarget(q[None], [0.05 * i + 0.5], at=0.05 * i)

    thread = threading.Thread(target=writer)
    thread.start()
    t = np.linspace(2.0, 3.0, 16)
    while thread.is_alive():
        version, path = s.snapshot()
        values = s(t)
        if s.version == version:
            try:
                np.testing.assert_array_equal(values, path(t))
            except AssertionError as e:
                errors.append(e)
    thread.join()
    assert not errors


def _frame_quat(frame):
    from trajgen.gimbal import forward

    return forward(frame.q)


def test_stream_frames_takes_a_change_from_the_next_frame():
    from trajgen.stream import stream_frames

    s = OnlineSpline([1, 0, 0, 0])
    s.retarget(Q.from_pan_tilt_roll([0.5, 0.2], [0.2, -0.1], [0.0, 0.1]), [0.8, 1.6], at=0.0)
    frames = stream_frames(s, 100.0)
    first = [next(frames) for _ in range(50)]
    _, old = s.snapshot()
    at = first[-1].t  # the last frame handed out: changes may start there
    with pytest.raises(ChangeTooLate):
        s.retarget(Q.from_pan_tilt_roll(0.0, 0.0, 0.0)[None], [at + 0.5], at=at - 0.01)
    s.retarget(Q.from_pan_tilt_roll(-0.5, 0.3, 0.0)[None], [at + 0.5], at=at)
    nxt = next(frames)
    assert nxt.index == 50 and nxt.t == pytest.approx(0.5)
    assert Q.distance(_frame_quat(nxt), s(nxt.t)) < 1e-12
    assert Q.distance(_frame_quat(nxt), old(nxt.t)) > 1e-9  # already off the old plan
    for f in first:
        assert Q.distance(_frame_quat(f), old(f.t)) < 1e-12
    s.close()
    rest = list(frames)
    assert rest[-1].t == pytest.approx(s.t_end) and s.t_end == pytest.approx(at + 0.5)
    np.testing.assert_allclose(rest[-1].qd, 0.0, atol=1e-9)
    # Joint angles move continuously: no step larger than the planned speed allows.
    q = np.array([f.q for f in first + [nxt] + rest])
    qd = np.array([f.qd for f in first + [nxt] + rest])
    step = np.abs(np.diff(q, axis=0))
    assert (step <= 0.01 * np.maximum(np.abs(qd[1:]), np.abs(qd[:-1])) + 1e-6).all()


def test_stream_frames_with_changes_from_another_thread(rng):
    from trajgen.stream import stream_frames

    s = OnlineSpline([1, 0, 0, 0])
    targets = random_quats(rng, 10, 30.0)
    frames = stream_frames(s, 200.0)
    got = [next(frames)]

    def writer():
        for q in targets:
            while True:
                try:
                    at = s.committed + 0.02
                    s.retarget(q[None], [at + 0.3], at=at)
                    break
                except ChangeTooLate:
                    continue

    thread = threading.Thread(target=writer)
    thread.start()
    while thread.is_alive():
        got.append(next(frames))
    thread.join()
    s.close()
    got += list(frames)
    assert [f.index for f in got] == list(range(len(got)))
    assert Q.distance(_frame_quat(got[-1]), targets[-1]) < 1e-9
    kept = [f for f in got if f.t > s.t_start]
    for f in kept:
        assert Q.distance(_frame_quat(f), s(f.t)) < 1e-12


@pytest.mark.parametrize("k", [1, 2, 3])
def test_splice_closed_form_matches_its_jet(rng, k):
    """The spliced segment's closed-form rates (what a stream evaluates) equal those
    of its jet (the exact reference), orders 0..3."""
    from trajgen.path import OrientationPath

    s = OnlineSpline(random_quats(rng, 1)[0], k=k)
    s.extend(random_quats(rng, 3), [0.6, 1.3, 2.0], at=0.0)
    for n in (1, 2):  # to one keyframe (then rest), and to two (then blends)
        s.retarget(random_quats(rng, n), 0.9 + 0.3 * n + np.arange(n), at=0.7 + 0.1 * n)
        splice = s._plan.pieces[-1].splice
        t = np.linspace(*splice.times, 9)
        q, rates = splice._space_rates(t, None, 3)
        q_ref, ref = OrientationPath._space_rates(splice, t, None, 3)
        np.testing.assert_allclose(q, q_ref, rtol=0, atol=1e-13)
        for order, (a, b) in enumerate(zip(rates, ref, strict=True), start=1):
            np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-10 * 10**order)
        for i, ti in enumerate(t):  # one time in floats (what a change starts from)
            q1, rates1 = splice.rates(float(ti))
            np.testing.assert_allclose(q1, q[i], rtol=0, atol=1e-13)
            for a, b in zip(rates1, rates, strict=True):
                np.testing.assert_allclose(a, b[i], rtol=0, atol=1e-12 * (1 + np.abs(b).max()))


@pytest.mark.parametrize("local", ["auto", "parabola", "circle"])
def test_log_of_a_local_curve_in_floats_matches_the_jet(rng, local):
    """What a two-keyframe splice ends on: the Taylor coefficients of log(C_1(t) q_a*)
    at T_1, in floats, against the jet reference, near the identity (series) and far."""
    from trajgen import derivatives as D
    from trajgen import jet as J
    from trajgen.online_splice import log_of_curve as _log_of_curve
    from trajgen.spline import BlendingSpline

    for spread in (1e-5, 1e-3, 1e-2, 0.1, 0.4, 0.8):
        q_a = Q.exp(rng.normal(size=(1, 3)))
        q = np.vstack([q_a, Q.mul(Q.exp(rng.normal(scale=spread, size=(2, 3))), q_a)])
        t = np.array([0.0, 0.4, 0.9 + rng.uniform()])
        spline = BlendingSpline(q, t, local=local)
        q_a = spline.quats[0]
        c1 = spline._curves.derivatives(np.array([0]), t[1:2], 3)
        c1 = np.array(c1)[..., 0] / np.array([1.0, 1.0, 2.0, 6.0])[:, None]
        d = J.Jet(D.hamilton(c1.T, Q.conj(q_a)[:, None]).T[:, :, None])
        reference = J.qlog(d).c[:, :, 0]
        got = _log_of_curve(spline._curves.kernel_table, 0, float(t[1]), q_a)
        tol = 1e-12 * (1 + np.abs(reference).max())
        np.testing.assert_allclose(got, reference, rtol=0, atol=tol)


@pytest.mark.parametrize("k", [1, 2, 3])
def test_one_keyframe_from_rest_is_the_offline_spline(rng, k):
    """From rest to one keyframe (no spline built): the offline rest spline's segment."""
    from trajgen.spline import BlendingSpline

    q = random_quats(rng, 2)
    s = OnlineSpline(q[0], 0.5, k=k)
    s.extend(q[1:], [1.7], at=0.5)
    offline = BlendingSpline(q, [0.5, 1.7], k=k)
    t = np.linspace(0.5, 1.7, 41)[:-1]  # order k + 1 jumps at the end (rest holds there)
    for order in range(min(k + 1, 3) + 1):
        np.testing.assert_allclose(s(t, order), offline(t, order), rtol=0, atol=1e-11)


def _moving(rng):
    s = OnlineSpline(random_quats(rng, 1)[0])
    s.extend(random_quats(rng, 3), [0.5, 1.0, 1.6], at=0.0)
    return s


def test_prepare_then_apply_is_the_change(rng):
    q, t = random_quats(rng, 2), [1.2, 1.9]
    s, twin = _moving(np.random.default_rng(5)), _moving(np.random.default_rng(5))
    s.retarget(q, t, at=0.7)
    steps = twin.prepare_steps("retarget", q, t, at=0.7)
    n = 0
    try:
        while True:
            next(steps)
            n += 1
    except StopIteration as done:
        change = done.value
    assert n >= 1  # the old path's jet, then the new piece
    assert twin.version == 1  # prepared, not made
    twin.apply(change)
    grid = np.linspace(0.0, 3.0, 301)
    assert twin.version == s.version
    for order in range(3):
        np.testing.assert_array_equal(twin(grid, order), s(grid, order))


def test_apply_refuses_a_change_prepared_on_an_older_path_or_before_a_streamed_time(rng):
    s = _moving(rng)
    first = s.prepare("retarget", random_quats(rng, 1), [1.2], at=0.7)
    second = s.prepare("retarget", random_quats(rng, 1), [1.3], at=0.7)
    s.apply(first)
    with pytest.raises(ChangeTooLate, match="changed since this change was prepared"):
        s.apply(second)
    late = s.prepare("retarget", random_quats(rng, 1), [1.5], at=0.8)
    assert s.commit(0.85, s.version)
    with pytest.raises(ChangeTooLate, match="before the streamed time"):
        s.apply(late)
    s.close()
    with pytest.raises(ValueError, match="closed"):
        s.prepare("extend", random_quats(rng, 1), [3.0], at=0.9)


def test_a_change_ahead_keeps_the_block_the_stream_evaluated(monkeypatch, rng):
    from trajgen import online_plan as online
    from trajgen.stream import stream_frames

    s = _moving(rng)  # blended from t = 0
    frames = stream_frames(s, 100.0)
    got = [next(frames) for _ in range(3)]  # frames of the first 16-frame block
    calls = []
    space_rates = online.Piece.space_rates

    def counted(piece, t, max_order):
        calls.append(len(t))
        return space_rates(piece, t, max_order)

    monkeypatch.setattr(online.Piece, "space_rates", counted)
    s.retarget(random_quats(rng, 1), [1.3], at=got[-1].t + 0.1)
    nxt = next(frames)
    assert nxt.index == 3 and calls == []  # the block evaluated before the change is kept
    assert Q.distance(_frame_quat(nxt), s(nxt.t)) < 1e-12
