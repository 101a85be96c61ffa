"""Render a simulated run to MP4 (offscreen; set ``MUJOCO_GL=egl`` on a headless machine)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from trajgen.sim.model import GimbalConfig, build_model

from .errors import BadArgument


def render_video(
    record,
    path,
    config: GimbalConfig | None = None,
    *,
    fps: int = 30,
    width: int = 320,
    height: int = 240,
) -> Path:
    """Write the gimbal's motion in ``record`` as an H.264 MP4, seen from the overview camera.

    Parameters
    ----------
    record : sim.run.SimRecord
        A simulated run (``TorqueReport.record``).
    path : str or Path
        Output file (.mp4).
    config : GimbalConfig, optional
        The gimbal that was simulated (default :class:`GimbalConfig`).
    fps : int
        Frames per second of the video.
    width, height : int
        Frame size (pixels), at most 640 x 480.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ModuleNotFoundError
        If ``imageio-ffmpeg`` (which ships an ffmpeg binary) is not installed.
    ValueError
        If ``fps``, ``width`` or ``height`` is out of range.
    """
    try:
        import imageio_ffmpeg
    except ModuleNotFoundError as e:
        raise ModuleNotFoundError(
            "writing MP4 needs the imageio-ffmpeg package: pip install imageio-ffmpeg"
        ) from e
    import mujoco

    if not (isinstance(fps, int) and fps > 0):
        raise BadArgument(f"Expected `fps` to be a positive int, got {fps!r}.")
    if not (0 < width <= 640 and 0 < height <= 480):
        raise BadArgument(f"Expected `width` x `height` within 640 x 480, got {width} x {height}.")
    model = build_model(config)
    data = mujoco.MjData(model)
    times = np.arange(record.t[0], record.t[-1], 1.0 / fps)
    path = Path(path)
    writer = imageio_ffmpeg.write_frames(str(path), (width, height), fps=fps, quality=7)
    writer.send(None)
    # A model without geoms on its links (a URDF, whose visuals MuJoCo discards) is
    # drawn as each link's equivalent-inertia box.
    option = mujoco.MjvOption()
    moving = model.body_dofnum[model.geom_bodyid] > 0 if model.ngeom else np.zeros(1, bool)
    option.flags[mujoco.mjtVisFlag.mjVIS_INERTIA] = not moving.any()
    with mujoco.Renderer(model, height, width) as renderer:
        for t in times:
            data.qpos[:] = [np.interp(t, record.t, q) for q in record.q.T]
            mujoco.mj_forward(model, data)
            renderer.update_scene(data, camera="overview", scene_option=option)
            renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
            writer.send(np.ascontiguousarray(renderer.render()))
    writer.close()
    return path
