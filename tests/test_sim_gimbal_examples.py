"""The gimbal examples (2 axes, a wrist, a URDF model) plan and pass ``trajgen sim``."""

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
