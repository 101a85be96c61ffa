"""Offscreen video of a simulated run, and the plot."""

import sys
from pathlib import Path

import pytest
from conftest import quintic_trajectory

from trajgen.sim.check import check_torque
from trajgen.sim.plot import plot_report
from trajgen.sim.run import simulate
from trajgen.sim.video import render_video

EXAMPLES = Path(__file__).parents[1] / "examples"


def test_video_is_an_mp4(tmp_path):
    pytest.importorskip("imageio_ffmpeg", reason="MP4 output needs imageio-ffmpeg")
    record = simulate(quintic_trajectory([1.0, 0.3, 0.2], 0.5))
    path = render_video(record, tmp_path / "run.mp4", fps=20)
    data = path.read_bytes()
    assert data[4:8] == b"ftyp"  # an ISO media file
    assert len(data) > 1000


def test_video_without_imageio_ffmpeg_says_what_to_install(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)
    record = simulate(quintic_trajectory([0.1, 0.0, 0.0], 0.1))
    with pytest.raises(ModuleNotFoundError, match=r"needs the imageio-ffmpeg package: pip install"):
        render_video(record, tmp_path / "run.mp4")


def test_video_refuses_frames_larger_than_the_offscreen_buffer(tmp_path):
    pytest.importorskip("imageio_ffmpeg", reason="MP4 output needs imageio-ffmpeg")
    record = simulate(quintic_trajectory([0.1, 0.0, 0.0], 0.1))
    with pytest.raises(ValueError, match=r"within 640 x 480, got 1280 x 720"):
        render_video(record, tmp_path / "run.mp4", width=1280, height=720)


def test_plot_is_written(tmp_path):
    report = check_torque(quintic_trajectory([1.0, 0.3, 0.2], 0.5))
    path = plot_report(report, tmp_path / "report.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("example", ["flex_roll_wrist.toml", "urdf_gimbal.toml"])
def test_video_of_a_two_axis_gimbal_and_of_a_urdf_shows_the_links(tmp_path, example):
    """A URDF's visuals are discarded by MuJoCo: its links are drawn as inertia boxes."""
    imageio_ffmpeg = pytest.importorskip("imageio_ffmpeg", reason="needs imageio-ffmpeg")
    import numpy as np

    report = check_torque(EXAMPLES / example)
    path = render_video(report.record, tmp_path / "run.mp4", report.config, fps=5)
    frames = imageio_ffmpeg.read_frames(str(path))
    width, height = next(frames)["size"]
    frame = np.frombuffer(list(frames)[len(report.record.t) // 2000], np.uint8)
    lit = frame.reshape(height, width, 3).max(axis=2) > 40
    assert lit.mean() > 0.005  # something of the gimbal is drawn
