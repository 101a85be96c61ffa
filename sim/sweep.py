"""Which payloads, servos and speeds does a motion work for? A sweep of the torque check.

Every variant (payload mass and offset, servo per joint, time scale) is the
same keyframe file run through :func:`trajgen.sim.check.build_report`, the
judge of ``trajgen sim``. The runs go through :func:`trajgen.sim.run.run_batch`,
as ``trajgen sim``'s single run does, here with many runs per call on several
threads, so a variant's figures equal ``check_torque``'s bit for bit (a test
holds both to it).

:func:`sweep_on_dask` runs the same chunks on a Dask cluster.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from trajgen.sim.model import GimbalConfig
from trajgen.validate import check_number

from .errors import BadArgument

_FAILED_PARTS = {"x envelope": "envelope", "torque limit": "limit", "tracking error": "tracking"}


@dataclass(frozen=True)
class Variant:
    """One point of a sweep.

    Attributes
    ----------
    payload_kg : float
        Camera mass (kg).
    payload_offset_m : tuple of 3 float
        Camera centre of mass in the roll link frame (m).
    servos : tuple of str
        Servo model per joint (pan, tilt, roll).
    time_scale : float
        Keyframe times are multiplied by this (0.5 = twice as fast).
    """

    payload_kg: float
    payload_offset_m: tuple
    servos: tuple
    time_scale: float

    def config(self, base: GimbalConfig) -> GimbalConfig:
        """``base`` with this variant's payload and servos."""
        return dataclasses.replace(
            base,
            payload_kg=self.payload_kg,
            payload_offset_m=tuple(self.payload_offset_m),
            servos=tuple(self.servos),
        )

    def label(self) -> str:
        servos = (
            "/".join(dict.fromkeys(self.servos))
            if len(set(self.servos)) == 1
            else ("/".join(self.servos))
        )
        offset = ",".join(f"{v:g}" for v in self.payload_offset_m)
        return f"{self.payload_kg:g} kg @ ({offset}) m, {servos}, x{self.time_scale:g}"


@dataclass(frozen=True)
class VariantResult:
    """The torque check's verdict on one variant.

    Attributes
    ----------
    variant : Variant
    ok : bool
        The verdict of ``trajgen sim``'s check.
    worst_margin_nm : float
        Smallest ``margin x envelope - |planned torque|`` over joints and samples (N m).
    worst_joint : str
        The joint where it occurs.
    failed : tuple of str
        Failed parts: ``"envelope"``, ``"limit"``, ``"tracking"``.
    duration_s : float
    max_tracking_error_rad : float
    steps_at_limit : int
        Summed over joints.
    """

    variant: Variant
    ok: bool
    worst_margin_nm: float
    worst_joint: str
    failed: tuple
    duration_s: float
    max_tracking_error_rad: float
    steps_at_limit: int


def variants(
    payload_kg: Sequence[float],
    payload_offset_m: Sequence[Sequence[float]],
    servos: Sequence[Sequence[str]],
    time_scale: Sequence[float],
) -> list[Variant]:
    """Every combination, in the order payload, offset, servo set, time scale (last fastest).

    Parameters
    ----------
    payload_kg : sequence of float
    payload_offset_m : sequence of 3-sequences of float
    servos : sequence of sequences of str (one name per joint)
        Servo sets (pan, tilt, roll).
    time_scale : sequence of float
        Each > 0.

    Raises
    ------
    ValueError
        If a sequence is empty or a time scale is not > 0.
    """
    axes = {
        "payload_kg": payload_kg,
        "payload_offset_m": payload_offset_m,
        "servos": servos,
        "time_scale": time_scale,
    }
    for name, values in axes.items():
        if len(values) == 0:
            raise BadArgument(f"Expected at least one value of `{name}`.")
    for s in time_scale:
        if not (isinstance(s, (int, float)) and math.isfinite(s) and s > 0):
            raise BadArgument(f"Expected every `time_scale` > 0, got {s!r}.")
    return [
        Variant(float(m), tuple(float(v) for v in o), tuple(str(s) for s in sv), float(k))
        for m, o, sv, k in itertools.product(payload_kg, payload_offset_m, servos, time_scale)
    ]


def _summary(variant: Variant, report) -> VariantResult:
    joints = list(report.joints.values())
    worst = min(joints, key=lambda j: j.worst_planned_margin_nm)
    failed = tuple(
        name for key, name in _FAILED_PARTS.items() if any(key in r for r in report.reasons)
    )
    return VariantResult(
        variant=variant,
        ok=report.ok,
        worst_margin_nm=worst.worst_planned_margin_nm,
        worst_joint=worst.name,
        failed=failed,
        duration_s=report.duration_s,
        max_tracking_error_rad=max(j.max_tracking_error_rad for j in joints),
        steps_at_limit=sum(j.steps_at_limit for j in joints),
    )


def run_sweep(
    source,
    sweep: Sequence[Variant],
    *,
    config: GimbalConfig | None = None,
    rate_hz: float | None = None,
    threads: int = 2,
    batch: int = 32,
    progress: Callable[[int, int], None] | None = None,
) -> list[VariantResult]:
    """Run the torque check on every variant on this machine (``mujoco.batch``, threads).

    Parameters
    ----------
    source : str, PathLike or KeyframeFile
        The keyframe file.
    sweep : sequence of Variant
        See :func:`variants`.
    config : GimbalConfig, optional
        What variants leave alone (torque margin, tracking limit, time step).
        Default: the file's ``[gimbal]`` table.
    rate_hz : float, optional
        Stream rate; default the file's, else 200 Hz.
    threads : int
        Rollout threads, >= 1.
    batch : int
        Variants per rollout call (memory: about ``batch x steps x 100`` bytes).
    progress : callable, optional
        Called with ``(done, total)`` after each batch.

    Returns
    -------
    list of VariantResult
        In the order of ``sweep``.

    Raises
    ------
    KeyframeFileError, KinematicsError, ValueError, TypeError
        For bad input (the path is checked once per time scale).
    SimulationError
        If MuJoCo warns in a run (the message names the variant).
    """
    from trajgen.keyframes import load_keyframe_file
    from trajgen.sim.check import DEFAULT_RATE_HZ

    if isinstance(source, str) or hasattr(source, "__fspath__"):
        source = load_keyframe_file(source)
    if config is None:
        from trajgen.sim.model import gimbal_config_from_tables

        config = gimbal_config_from_tables(source.tables, source.path, any_axes=True)
    threads = check_number("threads", threads, integer=True, low=1)
    rate = rate_hz or source.rate_hz or DEFAULT_RATE_HZ
    results: list[VariantResult | None] = [None] * len(sweep)
    by_scale: dict[float, list[int]] = {}
    for i, v in enumerate(sweep):
        by_scale.setdefault(v.time_scale, []).append(i)
    done = 0
    for scale, indices in by_scale.items():
        trajectory = scaled_trajectory(source, scale, rate, config.kinematics())
        for start in range(0, len(indices), batch):
            chunk = indices[start : start + batch]
            for i, report in zip(
                chunk,
                check_batch(trajectory, [sweep[i] for i in chunk], config, threads),
                strict=True,
            ):
                results[i] = _summary(sweep[i], report)
            done += len(chunk)
            if progress is not None:
                progress(done, len(sweep))
    return results


def scaled_trajectory(source, scale: float, rate_hz: float, kinematics=None):
    """The file's planned stream with keyframe times (from the first) multiplied by ``scale``
    (``kinematics``: the gimbal's ``GimbalKinematics``, default pan-tilt-roll)."""
    from trajgen.stream import plan_joint_trajectory

    times = source.times[0] + (source.times - source.times[0]) * scale
    spline = source.spline_class(source.quats, times, **source.spline_options)
    return plan_joint_trajectory(spline, rate_hz, kinematics)


def check_batch(trajectory, batch: Sequence[Variant], base: GimbalConfig, threads: int):
    """Full torque reports (:class:`TorqueReport`) of one trajectory under several variants.

    The variants' runs go through one :func:`trajgen.sim.run.run_batch` call on
    ``threads`` threads; each report is :func:`trajgen.sim.check.build_report`'s.
    Each variant's goals are led for that variant (``sim.lead.lead_trajectory``,
    the default lead), as ``check_torque`` leads them, and each run starts where
    its servos sag (``sim.lead.sagged_start``); variants whose lifts
    (``trajgen.lift``) differ in length run in batches of their own.
    """
    from trajgen.lead import DEFAULT_LEAD
    from trajgen.sim.check import build_report
    from trajgen.sim.lead import lead_trajectory, sagged_start
    from trajgen.sim.run import record_from_run, run_batch, simulation_model, step_controls

    configs = [v.config(base) for v in batch]
    models = [simulation_model(c) for c in configs]
    led = [
        lead_trajectory(trajectory, c, DEFAULT_LEAD, model=m)
        for c, m in zip(configs, models, strict=True)
    ]
    runs = [step_controls(t, base.timestep_s) for t, _, _ in led]
    starts = [sagged_start(t, c, m) for (t, _, _), c, m in zip(led, configs, models, strict=True)]
    records = [None] * len(batch)
    # Variants whose lifts (trajgen.lift) last as long run in one batch.
    for steps in sorted({len(t) for t, _ in runs}):
        ids = [b for b, (t, _) in enumerate(runs) if len(t) == steps]
        step_t = runs[ids[0]][0]
        ctrl = np.stack([runs[b][1] for b in ids])
        q, qd, torque = run_batch(
            [models[b] for b in ids],
            np.array([starts[b] for b in ids]),
            step_t[0],
            step_t,
            ctrl,
            threads=threads,
            labels=[batch[b].label() for b in ids],
        )
        for k, b in enumerate(ids):
            t = led[b][0]
            records[b] = record_from_run(t, configs[b], step_t, ctrl[k], q[k], qd[k], torque[k])
    return [
        build_report(
            t,
            c,
            records[b],
            model=models[b],
            lead=DEFAULT_LEAD,
            lead_notes=notes,
            goal_bounds_rad=goals.bounds,
        )
        for b, (c, (t, goals, notes)) in enumerate(zip(configs, led, strict=True))
    ]


def sweep_on_dask(
    source,
    sweep: Sequence[Variant],
    client,
    *,
    config: GimbalConfig | None = None,
    rate_hz: float | None = None,
    chunk: int = 8,
    progress: Callable[[int, int], None] | None = None,
) -> list[VariantResult]:
    """:func:`run_sweep` with chunks of ``chunk`` variants as tasks on a Dask cluster.

    Each task runs :func:`run_sweep` on one thread of a worker; results come
    back in the order of ``sweep`` and equal the single-machine run's.

    Parameters
    ----------
    source : str, PathLike or KeyframeFile
        Loaded here, sent to the workers as data (they need not see the file).
    client : distributed.Client
    chunk : int
        Variants per task.
    config, rate_hz, progress
        As for :func:`run_sweep`.
    """
    from distributed import as_completed

    from trajgen.keyframes import load_keyframe_file

    if isinstance(source, str) or hasattr(source, "__fspath__"):
        source = load_keyframe_file(source)
    parts = [list(sweep[i : i + chunk]) for i in range(0, len(sweep), chunk)]
    futures = [
        client.submit(
            run_sweep, source, part, config=config, rate_hz=rate_hz, threads=1, pure=False
        )
        for part in parts
    ]
    index = {f.key: k for k, f in enumerate(futures)}
    out: list = [None] * len(parts)
    done = 0
    for future in as_completed(futures):
        out[index[future.key]] = future.result()
        done += len(out[index[future.key]])
        if progress is not None:
            progress(done, len(sweep))
    return [r for part in out for r in part]
