"""Keyframe files (TOML): orientations at times, spline options, and tables for other packages.

```toml
[spline]            # optional
method = "smooth"   # SmoothSpline (default) or "blending" (BlendingSpline)
boundary = "rest"   # "rest", "natural" or "closed" (both methods)
knots = "quintic"   # SmoothSpline's knots: "end-minimax" (default at rest), "quintic"
                    # or "joint-minimax" (at rest; lower peak joint jerk, slower build)
                    # k, local, reparam are the blending spline's keywords; a file
                    # giving them without `method` gets method = "blending"

[stream]            # optional
rate_hz = 200

[[keyframes]]
t = 0.0             # seconds
pan = 0.0           # degrees: q = Rz(pan) Ry(tilt) Rx(roll); each defaults to 0
tilt = 0.0
roll = 0.0

[[keyframes]]
t = 1.5
quat = [1.0, 0.0, 0.0, 0.0]   # (w, x, y, z), instead of pan / tilt / roll

[timing]            # optional, written by `trajgen fit` (docs/fit.md): the path is
                    # the spline at `path_times`, played by the time law
                    # s(t) = path_times[0] + S sigma((t - t_1) / duration_s),
                    # sigma the clamped quintic B-spline (knots, coefficients);
                    # each keyframe's t must be the time the law passes it
path_times = [0.0, 1.5]
duration_s = 1.2
knots = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0]
coefficients = [0.0, 0.2, 0.4, 0.6, 0.8, 1.0]
```

Other top-level tables (``[gimbal]`` and ``[limits]`` for the simulator, ``[bus]``
for the drivers) are kept raw in :attr:`KeyframeFile.tables` for their packages to check
(``trajgen.cli.common.load_checked`` checks them all before any command works).
``[gimbal] axes`` and ``joints`` are read here too: keyframes then give angles by
those joint names (:mod:`trajgen.keyframe_axes`).
Keyframes are counted from 1 in messages, as a person reading the file would.

Angles are refused where the motion would not follow them as written
(:func:`check_angles`, :func:`check_honoured`, one rule for every command): tilt
within the lock margin of +-90 deg, an angle outside its joint's range, half a
turn or more of a joint between two keyframes, a first pan or roll outside
+-180 deg. A file is read up to :data:`MAX_FILE_BYTES`; a UTF-8 byte-order mark
is dropped.

Large files: ``tomllib`` takes about 100 s and 0.6 GB for a 70 MB file of a
million keyframes. The common layout, a run of ``[[keyframes]]`` tables whose
lines are each ``t``, ``pan``, ``tilt`` or ``roll`` ``= <decimal number>``, is
read by :func:`_read_keyframe_run` with one regular expression instead, and
only the rest of the file goes to ``tomllib``. Anything outside that subset of
TOML (quoted keys, ``quat``, ``inf``, underscores, a repeated key, an odd
line) makes the whole file go through ``tomllib``, so the result and every
message are exactly tomllib's.
"""

from __future__ import annotations

import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import quat as Q
from .axes import AxisSequence
from .errors import KeyframeFileError
from .gimbal import JOINT_NAMES, GimbalKinematics, angles_of
from .keyframe_axes import axes_from_table, axis_keyframes, is_default, written_angles
from .smooth import KNOTS, SmoothSpline
from .spline import BOUNDARIES, LOCALS, MAX_K, REPARAMS, BlendingSpline
from .timelaw import RetimedPath, TimeLaw
from .validate import check_choice, check_keys, check_number

#: The built-in example: a gentle pan/tilt look-around.
BUILTIN_EXAMPLE = Path(__file__).with_name("data") / "lookaround.toml"

#: Most bytes of a keyframe file read (a million keyframes take about 70 MB).
MAX_FILE_BYTES = 128 << 20

#: Build time (s) per keyframe of ``knots = "joint-minimax"`` on one unloaded core
#: (measured: 400 keyframes in 86 s with 4-5 processes per core, about 0.2 s each).
JOINT_MINIMAX_S_PER_KEYFRAME = 0.05
#: Most keyframes a file may plan with ``knots = "joint-minimax"`` (minutes of work).
JOINT_MINIMAX_MAX_KEYFRAMES = 5_000

#: The stream rate (Hz) every command uses when neither the command line nor
#: the file's ``[stream] rate_hz`` gives one.
DEFAULT_RATE_HZ = 200.0

SPLINE_KEYS = ("method", "k", "boundary", "local", "reparam", "knots")
#: ``[spline] method`` -> spline class. The default is chosen by the torque race
#: (docs/results.md, "The torque race, part 2").
METHODS = {"smooth": SmoothSpline, "blending": BlendingSpline}
DEFAULT_METHOD = "smooth"
#: Keys only the blending spline takes; a file giving one without ``method`` gets it.
BLENDING_ONLY = ("k", "local", "reparam")
STREAM_KEYS = ("rate_hz", "lead", "run_in_s")
KEYFRAME_KEYS = ("t", "pan", "tilt", "roll", "quat")
#: Keyframe angle fields (degrees), one per gimbal joint.
ANGLE_KEYS = JOINT_NAMES
#: How far (deg) a written keyframe angle may be from the one the path reaches there
#: (rounding through the quaternion).
_HONOURED_DEG = 1e-6
#: Top-level tables, and the package that checks each.
TABLES = {
    "spline": "trajgen",
    "keyframes": "trajgen",
    "stream": "trajgen",
    "gimbal": "sim",
    "bus": "drivers",
    "limits": "sim",
    "timing": "trajgen",
}
TIMING_KEYS = ("path_times", "duration_s", "knots", "coefficients")
#: How far (s) a keyframe's ``t`` may be from the time its ``[timing]`` law passes it.
TIMING_TOLERANCE_S = 1e-6

__all__ = [
    "BUILTIN_EXAMPLE",
    "DEFAULT_RATE_HZ",
    "KeyframeFile",
    "KeyframeFileError",
    "load_keyframe_file",
]


@dataclass(frozen=True)
class KeyframeFile:
    """A parsed, validated keyframe file.

    Attributes
    ----------
    path : Path
    times : ndarray, shape (N,)
        Keyframe times (s).
    quats : ndarray, shape (N, 4)
        Keyframe orientations (w, x, y, z).
    spline_options : dict
        Keywords for :class:`~trajgen.spline.BlendingSpline`.
    rate_hz : float or None
        The ``[stream]`` rate, if given.
    tables : dict
        Every other top-level table, as parsed (``tables.get("gimbal", {})``).
    method : str
        ``[spline] method``.
    lead : str or None
        The ``[stream] lead`` (``trajgen.lead.LEADS``), if given.
    run_in_s : float or None
        The ``[stream] run_in_s`` (s), if given: :meth:`spline` plays the path from
        rest and back to rest, each ramp this long (:mod:`trajgen.run_in`).
    """

    path: Path
    times: np.ndarray
    quats: np.ndarray
    spline_options: dict
    rate_hz: float | None = None
    tables: dict = field(default_factory=dict)
    #: ``[spline] method``: "smooth" or "blending".
    method: str = DEFAULT_METHOD
    #: ``[timing]``: the path's own keyframe times (N,) and the time law that plays
    #: it (:class:`~trajgen.timelaw.TimeLaw`), or None (the keyframe times are the clock).
    timing: tuple | None = None
    lead: str | None = None
    #: ``[gimbal] axes`` and ``joints`` (:mod:`trajgen.keyframe_axes`); ``quats`` are
    #: the orientations this gimbal has at the keyframes.
    axes: AxisSequence = field(default_factory=AxisSequence)
    run_in_s: float | None = None

    @property
    def spline_class(self) -> type[SmoothSpline] | type[BlendingSpline]:
        """The class ``[spline] method`` names, to build the file's spline at other
        times: ``kf.spline_class(kf.quats, times, **kf.spline_options)``."""
        return METHODS[self.method]

    def spline(self, progress=None) -> SmoothSpline | BlendingSpline:
        """The file's spline, built on first use and kept.

        Parameters
        ----------
        progress : callable, optional
            With ``knots = "joint-minimax"`` (the one slow build: about
            :data:`JOINT_MINIMAX_S_PER_KEYFRAME` s per keyframe), called with the
            fraction done (0..1) as the first build goes.

        Raises
        ------
        KeyframeFileError
            If the spline refuses the keyframes (a reversal with
            ``local = "circle"``, a ``"closed"`` loop that does not close).
        """
        built = self.__dict__.get("_built_spline")
        if built is None:
            times = self.times if self.timing is None else self.timing[0]
            try:
                options = dict(self.spline_options)
                if options.get("knots") == "joint-minimax":
                    options["progress"] = progress
                built = self.spline_class(self.quats, times, **options)
            except (ValueError, TypeError) as e:
                raise KeyframeFileError(f"{self.path}: {e}") from None
            if self.timing is not None:
                built = RetimedPath(built, self.timing[1])
            if self.run_in_s is not None:
                from .run_in import run_in

                try:
                    built = run_in(built, self.run_in_s)
                except ValueError as e:
                    raise KeyframeFileError(f"{self.path}: [stream] run_in_s: {e}") from None
            object.__setattr__(self, "_built_spline", built)  # a cache, not a field
        return built

    def stream_rate(self, rate_hz: float | None = None) -> float:
        """``rate_hz`` if given, else the file's ``[stream] rate_hz``, else the default.

        The default is :data:`DEFAULT_RATE_HZ`, the same for every command.
        """
        return rate_hz or self.rate_hz or DEFAULT_RATE_HZ

    def error(self, where: str, problem: str) -> KeyframeFileError:
        """A :class:`KeyframeFileError` for this file: ``"{path}: {where}: {problem}"``."""
        return KeyframeFileError(f"{self.path}: {where}: {problem}")


def _error(path: Path, where: str):
    """``problem -> KeyframeFileError("{path}: {where}: {problem}")``, for ``trajgen.validate``."""
    return lambda problem: KeyframeFileError(f"{path}: {where}: {problem}")


def load_keyframe_file(path) -> KeyframeFile:
    """Read and check a keyframe file.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    KeyframeFile

    Raises
    ------
    KeyframeFileError
        Missing or unreadable file, invalid TOML, an unknown table or key, a
        missing or mistyped field, times not increasing; the message names the
        file, the keyframe and the field. (What the spline itself refuses is
        raised by :meth:`KeyframeFile.spline`.)
    """
    path = Path(path)
    text = read_text(path)
    data, columns = _parse(text, path)
    check_keys(data, TABLES, error=lambda p: KeyframeFileError(f"{path}: {p}"), kind="table")
    axes = axes_from_table(data.get("gimbal", {}), path)
    if not is_default(axes):  # keyframes by the gimbal's joint names (trajgen.keyframe_axes)
        entries = (data if columns is None else _toml(text, path)).get("keyframes")
        columns = _keyframe_columns(axis_keyframes(entries, axes, path), path)
    if columns is None:
        columns = _keyframe_columns(data.get("keyframes"), path)
    options = _spline_options(data.get("spline", {}), path, len(columns["t"]))
    method = options.pop("method", DEFAULT_METHOD)
    stream = data.get("stream", {})
    rate_hz = _stream_rate(stream, path)
    times, quats = _keyframes(columns, path)
    if not is_default(axes):  # the angles written are the angles reached, as for pan-tilt-roll
        check_honoured(*written_angles(entries, axes), quats, path, axes)
    timing = _timing(data["timing"], times, path) if "timing" in data else None
    tables = {k: v for k, v in data.items() if TABLES[k] != "trajgen"}
    lead = _stream_lead(stream, path)
    return KeyframeFile(
        path,
        times,
        quats,
        options,
        rate_hz,
        tables,
        method=method,
        timing=timing,
        lead=lead,
        axes=axes,
        run_in_s=_stream_run_in(stream, path),
    )


def read_text(path) -> str:
    """The text of a keyframe file, read with a cap: at most :data:`MAX_FILE_BYTES`.

    A UTF-8 byte-order mark (as some editors write) is dropped.

    Raises
    ------
    KeyframeFileError
        Missing, a directory, unreadable, larger than the cap (``/dev/zero``),
        binary or not UTF-8; one line naming the file.
    """
    path = Path(path)
    try:
        with open(path, "rb") as f:
            data = f.read(MAX_FILE_BYTES + 1)
    except FileNotFoundError:
        stdin = " (standard input is not read: give a file name)" if str(path) == "-" else ""
        raise KeyframeFileError(f"{path}: no such file{stdin}") from None
    except IsADirectoryError:
        raise KeyframeFileError(f"{path}: is a directory, not a keyframe file") from None
    except OSError as e:
        raise KeyframeFileError(f"{path}: cannot read: {e.strerror or e}") from None
    if len(data) > MAX_FILE_BYTES:
        raise KeyframeFileError(
            f"{path}: more than {MAX_FILE_BYTES >> 20} MiB, the most a keyframe file may hold "
            "(about 1.5 million keyframes); is it a keyframe file?"
        )
    if b"\0" in data:
        raise KeyframeFileError(f"{path}: binary data (a NUL byte), not a TOML text file")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise KeyframeFileError(
            f"{path}: not UTF-8 text (byte 0x{data[e.start]:02x} at offset {e.start}); "
            "save it as UTF-8"
        ) from None


def _toml(text: str, path: Path) -> dict:
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise KeyframeFileError(f"{path}: invalid TOML: {e}") from None


def _parse(text: str, path: Path) -> tuple[dict, dict | None]:
    """The file's tables, and its keyframe columns when the fast reader could take them."""
    run = _read_keyframe_run(text)
    if run is not None:
        rest, columns = run
        try:
            data = tomllib.loads(rest)
        except tomllib.TOMLDecodeError:
            data = None  # let tomllib report it against the whole file
        if data is not None and "keyframes" not in data:
            return data, columns
    return _toml(text, path), None


# --- the fast reader -------------------------------------------------------------
_HEADER = re.compile(r"^[ \t]*\[\[keyframes\]\][ \t]*(?:#[^\n]*)?\r?$", re.M)
# A TOML decimal number without underscores (no leading zeros, as TOML requires).
_NUMBER = r"[+-]?(?:0|[1-9][0-9]*)(?:\.[0-9]+)?(?:[eE][+-]?[0-9]+)?"
_LINE = re.compile(
    r"^[ \t]*(?:(\[\[keyframes\]\])|(t|pan|tilt|roll)[ \t]*=[ \t]*(" + _NUMBER + r"))"
    r"[ \t]*(?:#[^\n]*)?\r?$",
    re.M,
)
_CONTENT = re.compile(r"^[ \t]*[^ \t\r\n#]", re.M)
_OTHER_HEADER = re.compile(r"^[ \t]*\[(?!\[keyframes\]\][ \t]*(?:#[^\n]*)?\r?$)", re.M)
_BLOCK_CHARS = 1 << 22  # read the run in pieces of about 4 MB to bound memory


def _read_keyframe_run(text: str) -> tuple[str, dict] | None:
    """Read the first run of plain ``[[keyframes]]`` tables with a regular expression.

    Returns
    -------
    tuple of (str, dict) or None
        The file without the run (for ``tomllib``) and the keyframe columns
        ``{"t", "pan", "tilt", "roll": float array (N,), NaN where absent}``;
        None if the run holds anything the reader does not handle.
    """
    first = _HEADER.search(text)
    if first is None:
        return None
    end_match = _OTHER_HEADER.search(text, first.start())
    end = len(text) if end_match is None else end_match.start()
    run = text[first.start() : end]
    codes = {"t": 0, "pan": 1, "tilt": 2, "roll": 3}
    pieces = []  # per block: keyframe index, key code, value of each key line
    n = 0
    start = 0
    while start < len(run):
        stop = len(run)
        if stop - start > _BLOCK_CHARS:
            cut = _HEADER.search(run, start + _BLOCK_CHARS)
            stop = cut.start() if cut else len(run)
        block = run[start:stop]
        found = _LINE.findall(block)
        if len(found) != len(_CONTENT.findall(block)):
            return None  # a line the reader does not handle
        headers = np.array([r[0] != "" for r in found])
        index = n + np.cumsum(headers) - 1
        key_lines = ~headers
        code = np.array([codes[r[1]] for r in found if r[1]], dtype=np.int8)
        value = np.array([r[2] for r in found if r[1]], dtype=float)
        pieces.append((index[key_lines], code, value))
        n += int(headers.sum())
        start = stop
    index, code, value = (np.concatenate(p) for p in zip(*pieces, strict=True))
    if np.bincount(index * 4 + code, minlength=4 * n).max(initial=0) > 1:
        return None  # a repeated key: tomllib's error
    table = np.full((n, 4), np.nan)
    table[index, code] = value
    columns = {key: table[:, c] for key, c in codes.items()}
    columns["quat"] = np.full((n, 4), np.nan)
    return text[: first.start()] + "\n" + text[end:], columns


# --- tables ------------------------------------------------------------------------
def _table(value, name: str, path: Path) -> dict:
    if not isinstance(value, dict):
        raise KeyframeFileError(f"{path}: [{name}] must be a table, got {value!r}")
    return value


def _spline_options(table, path: Path, keyframes: int) -> dict:
    """The ``[spline]`` table, checked: ``method`` and the keywords for its class
    (``keyframes``: how many the file has, for the cost of the slow knot choice)."""
    table = _table(table, "spline", path)
    check_keys(table, SPLINE_KEYS, error=_error(path, "[spline]"))
    if "k" in table:
        check_number(
            "k", table["k"], integer=True, low=1, high=MAX_K, error=_error(path, "[spline] k")
        )
    choices = (("method", tuple(METHODS)), ("boundary", BOUNDARIES), ("local", LOCALS))
    for key, allowed in (*choices, ("reparam", REPARAMS), ("knots", KNOTS)):
        if key in table:
            check_choice(key, table[key], allowed, error=_error(path, f"[spline] {key}"))
    blending_only = [k for k in BLENDING_ONLY if k in table]
    if "knots" in table and (table.get("method") == "blending" or blending_only):
        raise KeyframeFileError(f"{path}: [spline] knots: applies to method = 'smooth' only")
    if table.get("knots") == "joint-minimax" and keyframes > JOINT_MINIMAX_MAX_KEYFRAMES:
        minutes = keyframes * JOINT_MINIMAX_S_PER_KEYFRAME / 60
        raise KeyframeFileError(
            f"{path}: [spline] knots: 'joint-minimax' through {keyframes:,} keyframes would "
            f"take about {minutes:.0f} min, over the limit of {JOINT_MINIMAX_MAX_KEYFRAMES:,} "
            "keyframes; use knots = 'end-minimax' (milliseconds), or split the file"
        )
    if table.get("knots", "quintic") != "quintic" and table.get("boundary", "rest") != "rest":
        raise KeyframeFileError(
            f"{path}: [spline] knots: {table['knots']!r} needs boundary = 'rest', "
            f"got {table['boundary']!r}"
        )
    if blending_only and table.get("method") == "smooth":
        raise KeyframeFileError(
            f"{path}: [spline] {blending_only[0]}: applies to method = 'blending' only"
        )
    if blending_only and "method" not in table:  # a file written for the blending spline
        table = {"method": "blending", **table}
    return dict(table)


def _stream_rate(table, path: Path) -> float | None:
    """The ``[stream]`` table, checked: its ``rate_hz`` or None."""
    table = _table(table, "stream", path)
    check_keys(table, STREAM_KEYS, error=_error(path, "[stream]"))
    if "rate_hz" not in table:
        return None
    return check_number(
        "rate_hz", table["rate_hz"], low=0.0, low_open=True, error=_error(path, "[stream] rate_hz")
    )


def _timing(table, times: np.ndarray, path: Path) -> tuple[np.ndarray, TimeLaw]:
    """The ``[timing]`` table, checked against the keyframe ``times`` (N,): the path's
    own keyframe times (N,) and the law."""
    table = _table(table, "timing", path)
    check_keys(table, TIMING_KEYS, error=lambda p: KeyframeFileError(f"{path}: [timing] {p}"))
    for key in TIMING_KEYS:
        if key not in table:
            raise KeyframeFileError(f"{path}: [timing]: '{key}' is missing")
    arrays = {}
    for key in ("path_times", "knots", "coefficients"):
        value = table[key]
        where = _error(path, f"[timing] {key}")
        if not isinstance(value, list):
            raise where(f"expected a list of numbers, got {value!r}")
        arrays[key] = np.array([check_number(key, v, error=where) for v in value])
    duration = check_number(
        "duration_s",
        table["duration_s"],
        low=0.0,
        low_open=True,
        error=_error(path, "[timing] duration_s"),
    )
    s = arrays["path_times"]
    if len(s) != len(times) or (np.diff(s) <= 0).any():
        raise KeyframeFileError(
            f"{path}: [timing] path_times: expected {len(times)} increasing times (one per "
            f"keyframe), got {len(s)}"
        )
    try:
        law = TimeLaw(
            arrays["knots"], arrays["coefficients"], times[0], duration, s[0], s[-1] - s[0]
        )
    except ValueError as e:
        raise KeyframeFileError(f"{path}: [timing]: {e}") from None
    passed = law.inverse(s)
    off = np.abs(passed - times) > TIMING_TOLERANCE_S * max(1.0, duration)
    if off.any():
        i = _first(off)
        raise KeyframeFileError(
            f"{path}: keyframe {i + 1}: field 't': {times[i]:g} s, but the [timing] law passes "
            f"it at {passed[i]:.6f} s (delete [timing] to time the keyframes by hand)"
        )
    return s, law


def _stream_lead(table, path: Path) -> str | None:
    """The ``[stream] lead`` (checked by :func:`_stream_rate` to be in a table), or None."""
    if "lead" not in table:
        return None
    from .lead import LEADS

    return check_choice("lead", table["lead"], LEADS, error=_error(path, "[stream] lead"))


def _stream_run_in(table, path: Path) -> float | None:
    """The ``[stream] run_in_s`` (s, > 0), or None."""
    if "run_in_s" not in table:
        return None
    where = _error(path, "[stream] run_in_s")
    return check_number("run_in_s", table["run_in_s"], low=0.0, low_open=True, error=where)


# --- keyframes -----------------------------------------------------------------------
def _keyframe_columns(entries, path: Path) -> dict:
    """Type-check the parsed ``[[keyframes]]`` and lay them out as columns (see
    :func:`_read_keyframe_run`); a quaternion goes in ``"quat"`` (N, 4)."""
    if entries is None:
        raise KeyframeFileError(f"{path}: no [[keyframes]] (at least 2 are needed)")
    if not isinstance(entries, list):
        got = "one [keyframes] table" if isinstance(entries, dict) else repr(entries)
        raise KeyframeFileError(
            f"{path}: keyframes: expected a list of tables, each starting with a line "
            f"[[keyframes]] (two brackets), got {got}"
        )
    n = len(entries)
    columns = {key: np.full(n, np.nan) for key in ("t", *ANGLE_KEYS)}
    columns["quat"] = np.full((n, 4), np.nan)
    for i, kf in enumerate(entries):
        where = f"keyframe {i + 1}"
        if not isinstance(kf, dict):
            raise KeyframeFileError(f"{path}: {where}: expected a table, got {kf!r}")
        check_keys(kf, KEYFRAME_KEYS, error=_error(path, where), kind="field")
        for key, value in kf.items():
            field_error = _error(path, f"{where}: field '{key}'")
            if key != "quat":
                columns[key][i] = check_number(key, value, error=field_error)
            elif not isinstance(value, list) or len(value) != 4:
                raise field_error(f"expected [w, x, y, z], got {value!r}")
            else:
                columns["quat"][i] = [check_number(key, x, error=field_error) for x in value]
    return columns


def _first(mask: np.ndarray) -> int:
    return int(np.argmax(mask))


def check_keyframes(entries, source, *, minimum: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Check keyframe tables as a keyframe file's ``[[keyframes]]`` are checked.

    Parameters
    ----------
    entries : list of dict
        Keyframes: ``t`` (s) and ``quat`` ([w, x, y, z]) or any of ``pan``,
        ``tilt``, ``roll`` (degrees), e.g. parsed from JSON lines.
    source : str or Path
        What the message names before the keyframe, e.g. ``"stdin: line 7"``.
    minimum : int, optional
        Fewest keyframes accepted. Default 2.

    Returns
    -------
    times : ndarray, shape (N,)
    quats : ndarray, shape (N, 4)
        Unit quaternions (w, x, y, z).

    Raises
    ------
    KeyframeFileError
        ``"{source}: keyframe i: field 'f': ..."`` for the first problem.
    """
    return _keyframes(_keyframe_columns(entries, source), source, minimum)


def _keyframes(columns: dict, path: Path, minimum: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Check the keyframe columns as a whole; times (N,) and unit quaternions (N, 4)."""
    t, quat = columns["t"], columns["quat"]
    n = len(t)
    if n < minimum:
        raise KeyframeFileError(f"{path}: [[keyframes]]: at least {minimum} are needed, got {n}")
    has_quat = ~np.isnan(quat[:, 0])
    has_angle = ~np.isnan(np.column_stack([columns[k] for k in ANGLE_KEYS])).all(axis=1)
    if np.isnan(t).any():
        i = _first(np.isnan(t))
        raise KeyframeFileError(f"{path}: keyframe {i + 1}: field 't' is missing (seconds)")
    both = has_quat & has_angle
    if both.any():
        raise KeyframeFileError(
            f"{path}: keyframe {_first(both) + 1}: give either 'quat' or pan/tilt/roll, not both"
        )
    neither = ~has_quat & ~has_angle
    if neither.any():
        raise KeyframeFileError(
            f"{path}: keyframe {_first(neither) + 1}: no orientation: give 'quat' or "
            "pan/tilt/roll (degrees)"
        )
    if not math.isfinite(float(t[-1]) - float(t[0])):
        raise KeyframeFileError(
            f"{path}: keyframes 1 to {n}: field 't': the times span more than 1e308 s"
        )
    late = np.diff(t) <= 0
    if late.any():
        i = _first(late) + 1
        raise KeyframeFileError(
            f"{path}: keyframe {i + 1}: field 't': {t[i]:g} s is not after keyframe {i}'s "
            f"{t[i - 1]:g} s"
        )
    zero = has_quat & (np.hypot.reduce(np.nan_to_num(quat), axis=1) < 1e-12)  # no overflow
    if zero.any():
        raise KeyframeFileError(
            f"{path}: keyframe {_first(zero) + 1}: field 'quat': zero quaternion"
        )
    written = np.column_stack([np.nan_to_num(columns[k]) for k in ANGLE_KEYS])  # degrees
    check_angles(written, has_angle, path)
    pan, tilt, roll = np.radians(written).T
    quats = Q.as_quats(np.where(has_quat[:, None], quat, Q.from_pan_tilt_roll(pan, tilt, roll)))
    check_honoured(written, has_angle, quats, path)
    return t.copy(), quats


def check_angles(written: np.ndarray, has_angle: np.ndarray, path) -> None:
    """The one rule for keyframe angles, on every command: each within its joint's
    range, and tilt away from gimbal lock.

    Parameters
    ----------
    written : ndarray, shape (N, 3)
        Pan, tilt, roll as written (degrees; 0 where not given).
    has_angle : ndarray of bool, shape (N,)
        Keyframes given by angles (the others by ``quat``).
    path : str or Path
        Named in the message.

    Raises
    ------
    KeyframeFileError
        ``"{path}: keyframe i: field 'tilt': 90 deg is within 10 deg of gimbal lock
        (|tilt| <= 80 deg)"``, or an angle outside its joint's range.
    """
    kinematics = GimbalKinematics()
    lock_deg = 90.0 - math.degrees(kinematics.lock_margin_rad)
    limits = np.degrees(np.array(kinematics.limits_rad))
    for j, name in enumerate(ANGLE_KEYS):
        low, high = (-lock_deg, lock_deg) if name == "tilt" else limits[j]
        bad = has_angle & ((written[:, j] < low) | (written[:, j] > high))
        if bad.any():
            i = _first(bad)
            value = written[i, j]
            why = (
                f"within {90 - lock_deg:.1f} deg of gimbal lock (|tilt| <= {lock_deg:.1f} deg, "
                "where pan and roll turn about one axis)"
                if name == "tilt"
                else f"outside the {name} joint's range {low:g}..{high:g} deg"
            )
            raise KeyframeFileError(
                f"{path}: keyframe {i + 1}: field '{name}': {value:g} deg is {why}"
            )


def check_honoured(
    written: np.ndarray, has_angle: np.ndarray, quats: np.ndarray, path, axes=None
) -> None:
    """Refuse keyframe angles the path would not move through as written.

    The path joins orientations: between two keyframes it turns the shorter way,
    and the joint stream takes pan and roll continuously from the first
    keyframe's, in (-180, 180]. So the joint angles the stream reaches at each
    keyframe are the keyframe orientations' angles, unwrapped keyframe to
    keyframe. Where they differ from the angles written (two turns of pan that
    would be no motion, more than half a turn between two keyframes, a first
    pan of 300 that the stream reaches as -60), the keyframe is refused rather
    than moved through differently.

    The same rule holds for every gimbal (``axes``): its wrapped joints
    (:attr:`trajgen.axes.AxisSequence.wrapped`) are unwrapped keyframe to keyframe,
    and a two-axis gimbal's angles are those pointing its look axis as each keyframe
    does (a pan-tilt head's pan of 150 deg after a look at pan -45 deg is reached
    as -210 deg, the shorter way round: refused).

    Parameters
    ----------
    written : ndarray, shape (N, n)
        Joint angles as written (degrees): pan, tilt, roll, or the joints of ``axes``.
    has_angle : ndarray of bool, shape (N,)
        Keyframes given by angles (only those are compared).
    quats : ndarray, shape (N, 4)
        The keyframe orientations.
    path : str or Path
        Named in the message.
    axes : trajgen.axes.AxisSequence, optional
        The gimbal's axes and joint names; default pan-tilt-roll.

    Raises
    ------
    KeyframeFileError
        Naming the keyframe, the joint, what was written and what the path reaches.
    """
    seq = AxisSequence() if axes is None else axes
    if is_default(seq):
        reached = np.degrees(np.stack(angles_of(*quats.T, np.arctan2, np.hypot), axis=-1))
    else:
        reached = np.degrees(seq.angles(quats))
    cols = list(seq.wrapped)
    wraps = reached[:, cols]
    turns = np.zeros_like(wraps)
    turns[1:] = np.round((wraps[:-1] - wraps[1:]) / 360.0)
    # The first keyframe's pan or roll of +-180 is either end of the stream's range.
    edge = has_angle[0] & (np.abs(written[0, cols]) <= 180.0 + _HONOURED_DEG)
    turns[0] = np.where(edge, np.round((written[0, cols] - wraps[0]) / 360.0), 0.0)
    reached[:, cols] = wraps + 360.0 * np.cumsum(turns, axis=0)
    off = has_angle[:, None] & (np.abs(reached - written) > _HONOURED_DEG)
    if not off.any():
        return
    i, j = np.argwhere(off)[0]
    name, value, there = seq.joints[j], written[i, j], reached[i, j]
    if i > 0 and abs(value - written[i - 1, j]) >= 180.0:
        why = (
            f"{abs(value - written[i - 1, j]):g} deg from keyframe {i}'s {written[i - 1, j]:g}: "
            "the path turns the shorter way between two keyframes (less than half a turn "
            "per joint); add keyframes on the way"
        )
    else:
        why = (
            f"the path reaches this orientation with {name} at {there:.6g} deg; write that, "
            f"or add keyframes on the way (less than half a turn per joint between two)"
        )
    raise KeyframeFileError(f"{path}: keyframe {i + 1}: field '{name}': {value:g} deg: {why}")
