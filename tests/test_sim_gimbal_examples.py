"""The gimbal examples (2 axes, a wrist, a URDF model) plan, pass ``trajgen sim`` and
stream on ``--virtual``; fit, sweep, excite and identify run on them (and on the
shipped MJCF)."""

import csv
import json
from pathlib import Path

import numpy as np
import pytest

EXAMPLES = Path(__file__).parents[1] / "examples"


@pytest.mark.parametrize(
    ("name", "joints", "ids"),
    [
        ("pan_tilt_head.toml", ["pan", "tilt"], (11, 12)),
        ("flex_roll_wrist.toml", ["wrist_flex", "wrist_roll"], (14, 15)),
        ("urdf_gimbal.toml", ["pan", "tilt"], (1, 2)),
    ],
)
def test_a_gimbal_example_plans_and_passes_the_simulator(tmp_path, capsys, name, joints, ids):
    from trajgen.cli import main
    from trajgen.jobs import load_checked

    assert load_checked(EXAMPLES / name, any_axes=True).bus.joints.ids == ids

    out = tmp_path / "plan.csv"
    assert main(["plan", str(EXAMPLES / name), "--out", str(out)]) == 0
    header = out.read_text().splitlines()[0].split(",")
    assert [f"{j}_rad" for j in joints] == [h for h in header if h.endswith("_rad")]
    capsys.readouterr()
    assert main(["sim", str(EXAMPLES / name), "--json", str(tmp_path / "r.json")]) == 0
    text = capsys.readouterr().out
    assert text.startswith("torque check: OK")
    for joint in joints:
        assert f"\n{joint} " in text
    rows = np.loadtxt(out, delimiter=",", skiprows=1)
    assert np.isfinite(rows).all()
    # ... and streams on a virtual bus of its servos, on its ids (--configure: the head's
    # pan turns past half a turn, so bring-up sets Extended Position Mode)
    report = tmp_path / "stream.json"
    argv = ["stream", str(EXAMPLES / name), "--virtual", "--configure", "--json", str(report)]
    assert main(argv) == 0
    capsys.readouterr()
    run = json.loads(report.read_text())
    assert run["torque"]["ok"] and run["stream"]["fault"] == ""
    outcomes = run["servo_outcomes"]
    assert list(outcomes) == joints and [o["servo"] for o in outcomes.values()] == list(ids)


MJCF_FILE = """\
[gimbal]
axes = "zyx"
joints = ["pan", "tilt", "roll"]
model = "{model}"
servo = "XM430-W350"

[[keyframes]]
t = 0.0
pan = 0.0

[[keyframes]]
t = 1.5
pan = 40.0
tilt = 15.0
roll = -10.0

[[keyframes]]
t = 3.0
pan = 0.0
"""

MODELS = ["pan_tilt_head.toml", "flex_roll_wrist.toml", "urdf_gimbal.toml", "mjcf"]


def _example(tmp_path, name) -> Path:
    """A copy of an example in ``tmp_path`` (with its model, which a fitted file written
    there names as the example does), or a file on the shipped MJCF model (``"mjcf"``)."""
    if name != "mjcf":
        f = tmp_path / name
        text = (EXAMPLES / name).read_text()
        f.write_text(text)
        if "models/" in text:
            (tmp_path / "models").mkdir()
            urdf = "pan_tilt_head.urdf"
            (tmp_path / "models" / urdf).write_text((EXAMPLES / "models" / urdf).read_text())
        return f
    f = tmp_path / "mjcf.toml"
    f.write_text(MJCF_FILE.format(model=EXAMPLES / "models" / "pan_tilt_roll_gimbal.xml"))
    return f


@pytest.mark.parametrize("name", MODELS)
def test_fit_retimes_every_gimbal_example_and_the_result_passes(tmp_path, capsys, name):
    from trajgen.cli import main

    source, out = _example(tmp_path, name), tmp_path / "fitted.toml"
    assert main(["fit", str(source), "--out", str(out)]) == 0, capsys.readouterr().err
    capsys.readouterr()
    assert main(["sim", str(out)]) == 0
    assert capsys.readouterr().out.startswith("torque check: OK")


@pytest.mark.parametrize("name", MODELS)
def test_sweep_runs_on_every_gimbal_example(tmp_path, capsys, name):
    from trajgen.cli import main

    argv = ["sweep", str(_example(tmp_path, name)), "--time-scale", "1,2", "--threads", "1"]
    assert main(argv) == 0
    assert "2 of 2 variants pass" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("name", "joints"),
    [
        ("pan_tilt_head.toml", ("pan", "tilt")),
        ("flex_roll_wrist.toml", ("wrist_flex", "wrist_roll")),
        ("urdf_gimbal.toml", ("pan", "tilt")),
        ("mjcf", ("pan", "tilt", "roll")),
    ],
)
def test_excite_then_identify_recovers_each_joint_of_a_gimbal_example(
    tmp_path, capsys, name, joints
):
    """`trajgen excite --virtual` moves every joint of the chain by its own multisine, and
    `trajgen identify` on that log gives back the simulated servos' own parameters."""
    pytest.importorskip("mujoco.sysid", exc_type=ImportError)
    from trajgen.cli import main
    from trajgen.jobs import load_checked
    from trajgen.sim.excite import BAND_HZ

    log, fitted = tmp_path / "excite.csv", tmp_path / "fitted.toml"
    source = _example(tmp_path, name)
    argv = ["excite", str(source), "--virtual", "--seconds", "5", "--rate", "100"]
    assert main([*argv, "--telemetry", str(log)]) == 0, capsys.readouterr().err
    capsys.readouterr()
    with open(log, newline="") as fh:
        rows = [r for r in csv.DictReader(fh) if r["phase"] == "stream"]
    plan = np.array([[float(r[f"plan_rad_{j}"]) for j in joints] for r in rows])
    swing = np.degrees(plan.max(axis=0) - plan.min(axis=0))
    assert (swing > 20.0).all(), swing  # every joint excited (default +-25 / +-15 deg)
    spectrum = np.abs(np.fft.rfft(plan - plan.mean(axis=0), axis=0))
    peak_hz = np.fft.rfftfreq(len(plan), 0.01)[spectrum.argmax(axis=0)]
    assert ((peak_hz >= BAND_HZ[0] - 0.2) & (peak_hz <= BAND_HZ[1])).all()
    argv = ["identify", str(source), str(log), "--out", str(fitted), "--max-iter", "10"]
    assert main(argv) == 0, capsys.readouterr().err
    capsys.readouterr()
    truth = load_checked(source, spline=False, any_axes=True).gimbal
    fit = load_checked(fitted, spline=False, any_axes=True).gimbal
    assert fit.names == truth.names == joints
    for want, got in zip(truth.joints, fit.joints, strict=True):
        assert got.armature == pytest.approx(want.armature, rel=0.05)
        assert got.position_p_gain == pytest.approx(want.position_p_gain, rel=0.05)


def test_identify_refuses_to_write_away_from_a_relative_model(tmp_path, capsys):
    from trajgen.cli import main

    log = tmp_path / "log.csv"
    log.write_text("frame,t_s\n")
    argv = ["identify", str(EXAMPLES / "urdf_gimbal.toml"), str(log), "--out"]
    assert main([*argv, str(tmp_path / "fitted.toml")]) == 2
    assert capsys.readouterr().err == (
        f"trajgen identify: error: --out {tmp_path / 'fitted.toml'}: the file's [gimbal] "
        "model = 'models/pan_tilt_head.urdf' is relative to its folder; write the fitted "
        "file there\n"
    )
