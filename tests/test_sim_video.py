"""Offscreen video of a simulated run, and the plot."""

import sys

import pytest
from conftest import quintic_trajectory

from trajgen.sim.check import check_torque
from trajgen.sim.plot import plot_report
from trajgen.sim.run import simulate
from trajgen.sim.video import render_video


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
