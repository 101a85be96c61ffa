"""Tests on real servos: ``pytest -m hardware`` with TRAJGEN_PORT=/dev/ttyUSB0.

Needs three X-series servos with ids 1, 2, 3 (pan, tilt, roll) of the model in
TRAJGEN_MODEL (default XM430-W350), at TRAJGEN_BAUD (default 1000000), free to
move +-0.2 rad around their zero (tick 2048).
"""

import os

import numpy as np
import pytest

from trajgen.drivers.bringup import bring_up
from trajgen.drivers.bus import ServoBus
from trajgen.drivers.control_table import Register, model_named
from trajgen.drivers.streamer import Streamer
from trajgen.drivers.units import JointMap
from trajgen.stream import JointTrajectory

pytestmark = pytest.mark.hardware

MODEL = os.environ.get("TRAJGEN_MODEL", "XM430-W350")


@pytest.fixture
def bus():
    port = os.environ.get("TRAJGEN_PORT")
    if not port:
        pytest.skip("set TRAJGEN_PORT to the servo bus, e.g. /dev/ttyUSB0")
    with ServoBus(port, baud=int(os.environ.get("TRAJGEN_BAUD", "1000000"))) as opened:
        yield opened


def test_scan_finds_the_three_servos(bus):
    found = bus.scan()
    assert {1, 2, 3} <= set(found)
    assert all(found[i][0] == model_named(MODEL).number for i in (1, 2, 3))


def test_stream_small_sweep_tracks(bus, tmp_path):
    rate = 100.0
    t = np.arange(201) / rate
    s = t / t[-1]
    q = (0.2 * np.sin(np.pi * s) ** 2)[:, None] * np.array([1.0, 0.5, 0.25])
    trajectory = JointTrajectory(t, q, np.gradient(q, t, axis=0), np.zeros_like(q), rate)
    joints = JointMap()
    bring_up(bus, joints, (MODEL,) * 3, trajectory)
    stats = Streamer(bus, joints, telemetry=tmp_path / "t.csv", on_stop="torque_off").run(
        trajectory
    )
    assert stats.frames_sent == len(trajectory)
    assert stats.comm_errors == 0
    assert stats.achieved_rate_hz == pytest.approx(rate, rel=0.02)
    assert all(bus.read(i, Register.TORQUE_ENABLE) == 0 for i in joints.ids)
