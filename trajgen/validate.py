"""Input checks shared by the core, the simulator and the drivers.

One place for the type and range checks that every constructor and every table
of a keyframe file needs. Each check returns the value converted (``float``,
``int``, ``tuple``) or raises with a message that names the argument and what
arrived.

Two message forms, one per audience:

- library calls (``error=None``): ``TypeError`` for a wrong type,
  :class:`~trajgen.errors.BadArgument` (a ``TrajgenError``, so a ``ValueError``)
  for a wrong value, ``"Expected `k` to be an integer in 1..10, got 30."``;
- files (``error=`` a callable taking the problem text and returning the
  exception, e.g. a ``KeyframeFileError`` prefixed with file and field):
  ``"lookaround.toml: [spline] k: expected an integer in 1..10, got 30"``.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from .errors import BadArgument

ErrorFactory = Callable[[str], Exception] | None

#: Most characters of an unknown key a message shows (a JSON line's key may be megabytes).
_KEY_SHOWN = 40


def _raise(name: str, what: str, value, error: ErrorFactory, kind: type) -> None:
    if error is not None:
        raise error(f"expected {what}, got {value!r}")
    raise kind(f"Expected `{name}` to be {what}, got {value!r}.")


def _range_text(low, high, low_open: bool, high_open: bool) -> str:
    if low is not None and high is not None:
        if not low_open and not high_open:
            return f" in {low:g}..{high:g}"
        left, right = "(" if low_open else "[", ")" if high_open else "]"
        return f" in {left}{low:g}, {high:g}{right}"
    if low is not None:
        return f" {'>' if low_open else '>='} {low:g}"
    if high is not None:
        return f" {'<' if high_open else '<='} {high:g}"
    return ""


def check_number(
    name: str,
    value,
    *,
    low: float | None = None,
    high: float | None = None,
    low_open: bool = False,
    high_open: bool = False,
    integer: bool = False,
    error: ErrorFactory = None,
):
    """A finite real number (an integer if ``integer``) within the given bounds.

    Parameters
    ----------
    name : str
        Argument name, for the message.
    value : object
        What arrived. ``bool`` is refused (it is an ``int`` to Python, never a
        number to a person).
    low, high : float, optional
        Bounds; inclusive unless ``low_open`` / ``high_open``.
    integer : bool
        Require an integer (Python or numpy), returned as ``int``.
    error : callable, optional
        Builds the exception from the problem text (see the module docstring).

    Returns
    -------
    float or int

    Raises
    ------
    TypeError
        Not a number (``error`` not given).
    BadArgument
        Not finite or out of range (``error`` not given); a ``ValueError``.
    """
    kind = (int, np.integer) if integer else (int, float, np.integer, np.floating)
    what = ("an integer" if integer else "a finite number") + _range_text(
        low, high, low_open, high_open
    )
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, kind):
        _raise(name, what, value, error, TypeError)
    if not math.isfinite(value):
        _raise(name, what, value, error, BadArgument)
    if (low is not None and (value < low or (low_open and value == low))) or (
        high is not None and (value > high or (high_open and value == high))
    ):
        _raise(name, what, value, error, BadArgument)
    return int(value) if integer else float(value)


def check_numbers(
    name: str, value, count: int, *, integer: bool = False, error: ErrorFactory = None, **bounds
) -> tuple:
    """A list or tuple of exactly ``count`` numbers, each as :func:`check_number`.

    Returns
    -------
    tuple of float or int
    """
    if not isinstance(value, (list, tuple)) or len(value) != count:
        what = f"a list of {count} {'integers' if integer else 'numbers'}"
        _raise(
            name,
            what,
            value,
            error,
            TypeError if not isinstance(value, (list, tuple)) else BadArgument,
        )
    return tuple(
        check_number(
            f"{name}[{i}]", v, integer=integer, error=error and _whole(value, error), **bounds
        )
        for i, v in enumerate(value)
    )


def _whole(value, error: Callable[[str], Exception]) -> Callable[[str], Exception]:
    # In a file, name the whole list: "[bus] ids: expected an integer ..., got 1.5 in [1, 1.5, 3]".
    return lambda problem: error(f"{problem} in {value!r}")


def check_choice(name: str, value, allowed, *, error: ErrorFactory = None) -> str:
    """``value`` if it is one of the strings ``allowed``."""
    if not isinstance(value, str) or value not in allowed:
        if error is not None:
            raise error(f"expected one of {', '.join(allowed)}, got {value!r}")
        raise BadArgument(f"Expected `{name}` to be one of {tuple(allowed)}, got {value!r}.")
    return value


def check_keys(table: dict, known, *, error: Callable[[str], Exception], kind: str = "key") -> None:
    """Refuse the first key of ``table`` not in ``known``, listing the known ones.

    The one message shape for every table of every file: ``"unknown {kind} 'x'
    (known: a, b, c)"``, ``kind`` e.g. "key", "field", "table", "joint".

    Parameters
    ----------
    table : dict
    known : iterable of str
    error : callable
        Builds the exception from the message (prefixing file and table).
    kind : str
        What a key of this table is, for the message.
    """
    for key in table:
        if key not in known:
            shown = key if len(key) <= _KEY_SHOWN else key[:_KEY_SHOWN] + "..."
            raise error(f"unknown {kind} '{shown}' (known: {', '.join(known)})")
