"""A small TOML writer for the documents keyframe files hold (``tomllib`` only reads).

It writes what ``tomllib`` parses back into the same dict: tables, arrays of
tables, inline tables inside arrays and values, strings, booleans, integers,
finite and non-finite floats, and arrays of those. Dates are not supported
(no keyframe file has one) and raise ``TypeError``. Comments of a file that
was read are not kept: ``tomllib`` drops them.
"""

from __future__ import annotations

import math
import re

_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")
_ESCAPES = {
    '"': '\\"',
    "\\": "\\\\",
    "\b": "\\b",
    "\t": "\\t",
    "\n": "\\n",
    "\f": "\\f",
    "\r": "\\r",
}


def dumps(document: dict) -> str:
    """TOML text of ``document``, a dict as :func:`tomllib.loads` returns.

    Plain values come first, then sub-tables (``[name]``), then arrays of
    tables (``[[name]]``, for a list whose items are all dicts), each in the
    dict's order.

    Parameters
    ----------
    document : dict
        String keys; values str, bool, int, float, list or dict.

    Returns
    -------
    str
        ``tomllib.loads(dumps(d)) == d`` for every such ``d``.

    Raises
    ------
    TypeError
        For a key that is not a string or a value of another type.
    """
    if not isinstance(document, dict):
        raise TypeError(f"Expected `document` to be a dict, got {type(document).__name__}.")
    lines: list[str] = []
    _table(document, (), lines)
    return "\n".join(lines).lstrip("\n") + "\n"


def _is_table_array(value) -> bool:
    return isinstance(value, list) and bool(value) and all(isinstance(v, dict) for v in value)


def _table(table: dict, path: tuple[str, ...], lines: list[str]) -> None:
    plain = {k: v for k, v in table.items() if not isinstance(v, dict) and not _is_table_array(v)}
    for key, value in plain.items():
        lines.append(f"{_key(key)} = {_value(value)}")
    for key, value in table.items():
        if isinstance(value, dict):
            sub = (*path, key)
            lines.extend(["", "[" + ".".join(_key(k) for k in sub) + "]"])
            _table(value, sub, lines)
    for key, value in table.items():
        if _is_table_array(value):
            sub = (*path, key)
            for item in value:
                lines.extend(["", "[[" + ".".join(_key(k) for k in sub) + "]]"])
                _table(item, sub, lines)


def _key(key) -> str:
    if not isinstance(key, str):
        raise TypeError(f"TOML keys are strings, got {type(key).__name__} {key!r}.")
    return key if _BARE_KEY.fullmatch(key) else _string(key)


def _string(text: str) -> str:
    out = []
    for ch in text:
        if ch in _ESCAPES:
            out.append(_ESCAPES[ch])
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04x}")
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'


def _value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return _string(value)
    if isinstance(value, list):
        return "[" + ", ".join(_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{_key(k)} = {_value(v)}" for k, v in value.items()) + "}"
    raise TypeError(f"Cannot write {type(value).__name__} {value!r} as TOML.")
