"""`trajgen sweep` on mujoco.batch: the same verdicts, bit for bit, as `trajgen sim`."""

import argparse
import json

import mujoco
import numpy as np
import pytest

from trajgen.keyframes import load_keyframe_file
from trajgen.sim import GimbalConfig, check_torque
from trajgen.sim.run import run_batch, simulation_model, step_controls
from trajgen.sim.sweep import (
    Variant,
    check_batch,
    run_sweep,
    scaled_trajectory,
    variants,
)

KEYS = """\
[stream]
rate_hz = 100

[gimbal]  # torque decides here: pan at 2 rad/s lags 45 ms x speed (0.09 rad)
max_tracking_error_rad = 0.2

[[keyframes]]
t = 0.0
pan = 0.0

[[keyframes]]
t = 0.6
pan = 40.0
tilt = -10.0

[[keyframes]]
t = 1.2
pan = 0.0
tilt = 10.0
"""


@pytest.fixture(scope="module")
def keys(tmp_path_factory):
    path = tmp_path_factory.mktemp("sweep") / "keys.toml"
    path.write_text(KEYS)
    return load_keyframe_file(path)


SMALL = variants(
    [0.15, 2.5],
    [(0.03, 0.0, 0.0)],
    [("XM430-W350",) * 3, ("XM430-W350", "XL430-W250", "XM430-W350")],
    [0.3, 1.0],
)


def test_rollout_equals_check_torque_bit_for_bit(keys):
    """Each variant's rolled-out run is `simulate`'s run: same q, qd, torque, verdict."""
    by_scale = {}
    for v in SMALL:
        by_scale.setdefault(v.time_scale, []).append(v)
    for scale, batch in by_scale.items():
        trajectory = scaled_trajectory(keys, scale, 100.0)
        reports = check_batch(trajectory, batch, GimbalConfig(), threads=2)
        for v, got in zip(batch, reports, strict=True):
            want = check_torque(trajectory, config=v.config(GimbalConfig()))
            for name in ("q", "qd", "torque_nm", "at_limit", "planned"):
                np.testing.assert_array_equal(getattr(got.record, name), getattr(want.record, name))
            assert got.ok == want.ok and got.reasons == want.reasons


def test_batch_on_two_threads_equals_python_loop_bit_for_bit(keys):
    """run_batch on 2 threads and a plain mj_step loop give identical arrays.

    The first variant has no payload (one geom fewer), so it runs in a batch of its own.
    """
    trajectory = scaled_trajectory(keys, 0.5, 100.0)
    base = GimbalConfig()
    payloads = variants([0.0, 0.15, 2.5], [(0.03, 0.0, 0.0)], [SMALL[0].servos], [1.0])
    configs = [v.config(base) for v in payloads]
    models = [simulation_model(c) for c in configs]
    step_t, ctrl = step_controls(trajectory, base.timestep_s)
    q, qd, torque = run_batch(
        models, trajectory.q[0], step_t[0], step_t, np.stack([ctrl] * len(models)), threads=2
    )
    for b, model in enumerate(models):
        data = mujoco.MjData(model)
        data.qpos[:] = trajectory.q[0]
        data.time = trajectory.t[0]
        mujoco.mj_forward(model, data)
        for k in range(len(ctrl)):
            assert np.array_equal(data.qpos, q[b, k]) and np.array_equal(data.qvel, qd[b, k])
            data.ctrl[:] = ctrl[k]
            mujoco.mj_step(model, data)
            assert np.array_equal(data.actuator_force, torque[b, k])


def test_sweep_finds_the_failing_variants(keys):
    results = run_sweep(keys, SMALL, threads=2)
    assert [r.variant for r in results] == SMALL
    by = {(r.variant.payload_kg, r.variant.servos[1], r.variant.time_scale): r for r in results}
    # Slow and light passes on either servo; fast fails on the small XL430 tilt with 2.5 kg.
    assert by[(0.15, "XM430-W350", 1.0)].ok
    assert by[(0.15, "XL430-W250", 1.0)].ok
    fast_heavy_small = by[(2.5, "XL430-W250", 0.3)]
    assert not fast_heavy_small.ok and fast_heavy_small.worst_margin_nm < 0
    assert "envelope" in fast_heavy_small.failed
    # Margins shrink with payload and speed.
    assert (
        by[(2.5, "XM430-W350", 1.0)].worst_margin_nm < by[(0.15, "XM430-W350", 1.0)].worst_margin_nm
    )


def test_sweep_on_dask_local_cluster_matches(keys):
    distributed = pytest.importorskip("distributed")
    from trajgen.sim.sweep import sweep_on_dask

    single = run_sweep(keys, SMALL, threads=1)
    with (
        distributed.LocalCluster(
            n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None
        ) as cluster,
        distributed.Client(cluster) as client,
    ):
        seen = []
        remote = sweep_on_dask(keys, SMALL, client, chunk=3, progress=lambda d, n: seen.append(d))
    assert remote == single
    assert seen[-1] == len(SMALL)


def test_variants_and_errors():
    vs = variants([0.1, 0.2], [(0, 0, 0)], [("XM430-W350",) * 3], [1.0, 2.0])
    assert [(v.payload_kg, v.time_scale) for v in vs] == [
        (0.1, 1.0),
        (0.1, 2.0),
        (0.2, 1.0),
        (0.2, 2.0),
    ]
    with pytest.raises(ValueError, match="Expected every `time_scale` > 0"):
        variants([0.1], [(0, 0, 0)], [("XM430-W350",) * 3], [0.0])
    with pytest.raises(ValueError, match="Expected at least one value of `payload_kg`"):
        variants([], [(0, 0, 0)], [("XM430-W350",) * 3], [1.0])
    with pytest.raises(ValueError, match="unknown model"):
        Variant(0.1, (0, 0, 0), ("XM999",) * 3, 1.0).config(GimbalConfig())


def _sweep_cli(argv):
    from trajgen.cli.sweep import register

    parser = argparse.ArgumentParser(prog="trajgen")
    register(parser.add_subparsers())
    args = parser.parse_args(["sweep", *map(str, argv)])
    return args.func(args)


def test_cli_table_plot_json(keys, tmp_path, capsys):
    status = _sweep_cli(
        [
            keys.path,
            "--payload-kg",
            "0.15,2.5",
            "--servo",
            "tilt=XM430-W350,XL430-W250",
            "--time-scale",
            "0.3,1",
            "--plot",
            tmp_path / "s.png",
            "--json",
            tmp_path / "s.json",
        ]
    )
    out = capsys.readouterr().out
    assert status == 0
    assert "worst margin" in out and "of 8 variants pass" in out and "FAIL" in out
    assert (tmp_path / "s.png").stat().st_size > 10_000
    assert len(json.loads((tmp_path / "s.json").read_text())) == 8


def test_cli_bad_input(keys, capsys):
    from trajgen.cli import main

    assert main(["sweep", str(keys.path), "--servo", "tilt=XM999"]) == 2
    assert "unknown model 'XM999'" in capsys.readouterr().err
    assert main(["sweep", str(keys.path), "--servo", "yaw=XM430-W350"]) == 2
    assert capsys.readouterr().err == (
        "trajgen sweep: error: --servo yaw=...: no joint 'yaw' (the file's gimbal has pan, "
        "tilt, roll)\n"
    )
    with pytest.raises(SystemExit):
        _sweep_cli([keys.path, "--servo", "yaw"])
