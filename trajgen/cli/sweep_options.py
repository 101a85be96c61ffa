"""The options of ``trajgen sweep`` (argparse types) and the variants they make, each
checked before any simulation: joints and servo models by name, the payload
against the file's own model, every payload, offset and time scale as the
gimbal and the stream take it, and the count against ``--max-variants``."""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import math

import numpy as np

from trajgen.cli.arguments import positive_float
from trajgen.cli.messages import BadInput

#: Variants a sweep runs without --max-variants (each a whole simulation).
MAX_VARIANTS = 1_000


def masses(text: str) -> list[float]:
    """argparse type: comma-separated masses (kg), each > 0 or a bare 0 (no payload)."""
    return [0.0 if v.strip() == "0" else positive_float(v) for v in text.split(",")]


def scales(text: str) -> list[float]:
    """argparse type: comma-separated time multipliers, each > 0."""
    return [positive_float(v) for v in text.split(",")]


def offset(text: str) -> tuple[float, float, float]:
    """argparse type: ``x,y,z`` (m), three finite numbers."""
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected x,y,z in m, got {text!r}") from None
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected 3 finite numbers x,y,z in m, got {text!r}")
    return values


def servo_choice(text: str) -> tuple[str, list[str]]:
    """argparse type: ``JOINT=MODEL[,MODEL...]``."""
    joint, sep, models = text.partition("=")
    if not sep or not joint or not models:
        raise argparse.ArgumentTypeError(
            f"expected JOINT=MODEL[,MODEL...] with JOINT a joint of the file's gimbal, got {text!r}"
        )
    return joint, models.split(",")


def sweep_variants(args, source, base) -> list:
    """The ``trajgen.sim.sweep.Variant`` list of the options ``args`` over the keyframe
    file ``source`` and its gimbal ``base``; no simulation.

    Raises
    ------
    BadInput
        Naming the option: an unknown joint or servo model, a payload on the file's own
        model, a payload, offset or time scale the gimbal or the stream cannot take,
        more than ``--max-variants`` variants.
    """
    from trajgen.sampling import MAX_SAMPLES, check_sample_count
    from trajgen.sim import sweep

    per_joint = {j: [s.name] for j, s in zip(base.names, base.servos, strict=True)}
    for joint, models in args.servo or []:
        if joint not in per_joint:
            raise BadInput(
                f"--servo {joint}=...: no joint {joint!r} (the file's gimbal has "
                f"{', '.join(base.names)})"
            )
        per_joint[joint] = models
    servo_sets = list(itertools.product(*(per_joint[j] for j in base.names)))
    if base.model is not None and (args.payload_kg or args.offset_m):
        raise BadInput(
            f"--{'payload-kg' if args.payload_kg else 'offset-m'}: the payload of your own "
            f"model ([gimbal] model = {base.model.name!r}) is in that file, not a parameter"
        )
    for field, option, values in (
        ("payload_kg", "--payload-kg", args.payload_kg or ()),
        ("payload_offset_m", "--offset-m", args.offset_m or ()),
    ):
        for value in values:
            try:
                dataclasses.replace(base, **{field: value})
            except ValueError as e:
                shown = ",".join(f"{v:g}" for v in np.atleast_1d(value))
                raise BadInput(f"{option} {shown}: {e}") from None
    payloads = args.payload_kg or [base.payload_kg]
    offsets = args.offset_m or [base.payload_offset_m]
    count = len(payloads) * len(offsets) * len(servo_sets) * len(args.time_scale)
    if count > args.max_variants:
        raise BadInput(
            f"{count:,} variants ({len(payloads)} payloads x {len(offsets)} offsets x "
            f"{len(servo_sets)} servo sets x {len(args.time_scale)} time scales), over the "
            f"limit of {args.max_variants:,}; --max-variants N raises it"
        )
    variants = sweep.variants(payloads, offsets, servo_sets, args.time_scale)
    for v in variants:  # unknown servo names fail here, before any work
        try:
            v.config(base)
        except ValueError as e:
            raise BadInput(f"--servo: {e}") from None
    rate = source.stream_rate(args.rate)
    gap = float(np.diff(source.times).min())
    for scale in args.time_scale:
        if gap * scale < 1.0 / rate:
            raise BadInput(
                f"--time-scale {scale:g}: puts keyframes {gap * scale:.3g} s apart, less than "
                f"one sample period ({1 / rate:.3g} s at {rate:g} Hz)"
            )
        try:
            check_sample_count(source.times[0] * scale, source.times[-1] * scale, rate, MAX_SAMPLES)
        except ValueError as e:
            raise BadInput(f"--time-scale {scale:g}: {e}") from None
    return variants
