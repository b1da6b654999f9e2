"""Validators for plain input data (scene files, dicts, keyword arguments).

Every function takes the value, the field's name as the user wrote it (``medium.albedo``,
``lights[0].irradiance``) and the source (a file name, ``<dict>``), and either returns the value
in canonical form or raises :class:`~popvol.errors.PopvolError` with one line naming the
source, the field, the value and what is allowed, e.g.

    scene.toml: lights[0].irradiance = 'x' must be 1 or 3 finite numbers >= 0

Any input is accepted without a TypeError or ValueError escaping: strings, None, nested or
ragged lists, dicts, bools (refused where a number is wanted), huge integers, NaN and inf.
"""
from __future__ import annotations

import math
import numbers

import numpy as np

from .errors import PopvolError

__all__ = ["rgb", "power", "vector", "integer", "number", "choice", "known_keys", "table", "text",
           "MAX_POWER"]

_SHOW_MAX = 60        # characters of a bad value quoted in a message

#: Largest irradiance, intensity or radiance (and environment-map scale) accepted. The renderer
#: multiplies a light's power by fields per unit power, phase functions (up to ~1e14 for g near
#: 1 in float32) and 1 / r^2 and stores float32 pixels (at most 3.4e38): 1e20 leaves that room.
MAX_POWER = 1e20


def rgb(value, name: str, src: str, lo: float = 0.0, hi: float = math.inf) -> np.ndarray:
    """float64 (3,) from one number (grey) or three (RGB), each finite and in [lo, hi]."""
    xs = _numbers(value)
    if xs is None or len(xs) not in (1, 3) or not all(_finite(x) and lo <= x <= hi for x in xs):
        raise _error(src, name, value, f"must be 1 or 3 finite numbers{_range(lo, hi, False, ' ')}")
    return np.array(xs * 3 if len(xs) == 1 else xs, np.float64)


def power(value, name: str, src: str, hi: float = MAX_POWER) -> np.ndarray:
    """:func:`rgb` >= 0 and at most ``hi`` (a light's power, a radiance, a scale): larger values
    overflow float32 once multiplied by the fields, so they are refused here, by name."""
    xs = _numbers(value)
    if xs is None or len(xs) not in (1, 3) or not all(_finite(x) and 0 <= x <= hi for x in xs):
        raise _error(src, name, value, f"must be 1 or 3 finite numbers >= 0, at most {hi:g}")
    return np.array(xs * 3 if len(xs) == 1 else xs, np.float64)


def text(value, name: str, src: str, max_length: int = 4096) -> str:
    """A string (a file or grid name) of at most ``max_length`` characters, without control
    characters (a message quoting it must stay one line)."""
    if not isinstance(value, str):
        raise _error(src, name, value, "must be a string")
    if len(value) > max_length or not value.isprintable():
        raise _error(src, name, value, f"must be a string of at most {max_length} printable characters")
    return value


def vector(value, name: str, src: str, nonzero: bool = False, positive: bool = False) -> np.ndarray:
    """float64 (3,) from three finite numbers; ``nonzero``: not all 0; ``positive``: each > 0."""
    xs = _numbers(value)
    ok = xs is not None and len(xs) == 3 and all(_finite(x) for x in xs)
    ok = ok and not (nonzero and all(x == 0 for x in xs)) and not (positive and min(xs) <= 0)
    if not ok:
        extra = ", each > 0" if positive else (", not all 0" if nonzero else "")
        raise _error(src, name, value, f"must be 3 finite numbers{extra}")
    return np.array(xs, np.float64)


def integer(value, name: str, src: str, lo: int, hi: int) -> int:
    """An integer in [lo, hi] (``hi`` may be ``math.inf``). Bools and floats are refused."""
    ok = _is_int(value) and lo <= int(value) <= hi
    if not ok:
        raise _error(src, name, value, f"must be an integer{_range(lo, hi, False, ' ')}")
    return int(value)


def number(value, name: str, src: str, lo: float, hi: float, open_interval: bool = False) -> float:
    """A finite number in [lo, hi], or in (lo, hi) with ``open_interval``. Bools are refused."""
    xs = _numbers(value) if _is_scalar(value) else None
    x = xs[0] if xs else math.nan
    inside = (lo < x < hi) if open_interval else (lo <= x <= hi)
    if not (_finite(x) and inside):
        raise _error(src, name, value, f"must be a finite number{_range(lo, hi, open_interval, ' ')}")
    return float(x)


def choice(value, name: str, src: str, allowed) -> str:
    """One of the strings ``allowed``."""
    allowed = tuple(allowed)
    if not (isinstance(value, str) and value in allowed):
        raise _error(src, name, value, f"must be one of {', '.join(repr(a) for a in allowed)}")
    return value


def known_keys(table: dict, known, prefix: str, src: str) -> None:
    """Refuse a key of ``table`` that is not in ``known``, listing the known ones.

    ``prefix`` is the table's path with a trailing dot (``"medium."``; ``""`` at the top)."""
    known = set(known)
    for k in table:
        if k not in known:
            shown = k if isinstance(k, str) and len(k) <= _SHOW_MAX and k.isprintable() else _show(k)
            raise PopvolError(f"{src}: unknown key {prefix}{shown} "
                              f"(known: {', '.join(sorted(known))})")


def table(value, name: str, src: str) -> dict:
    """A table (dict)."""
    if not isinstance(value, dict):
        raise PopvolError(f"{src}: {name} must be a table, got {_show(value)}")
    return value


# ---------------------------------------------------------------------------------------------

def _is_real(x) -> bool:
    """A real number and not a bool (numbers.Real covers int, float and NumPy's scalars)."""
    return isinstance(x, numbers.Real) and not isinstance(x, (bool, np.bool_))


def _is_scalar(x) -> bool:
    """One number: a real number or a 0-D numeric array."""
    return _is_real(x) or (isinstance(x, np.ndarray) and x.ndim == 0 and x.dtype.kind in "iuf")


def _is_int(x) -> bool:
    return isinstance(x, (int, np.integer)) and not isinstance(x, (bool, np.bool_))


def _as_float(x) -> float:
    try:
        return float(x)
    except (OverflowError, TypeError, ValueError):     # e.g. 10**400
        return math.inf if x > 0 else -math.inf


def _finite(x: float) -> bool:
    return math.isfinite(x)


_MAX_NUMBERS = 16     # the longest list of numbers any field takes is 3


def _numbers(value) -> list[float] | None:
    """A flat list of floats from a number, a list/tuple of numbers or a 0-/1-D numeric array;
    None for anything else (strings, None, nested lists, dicts, bools)."""
    if _is_real(value):
        return [_as_float(value)]
    if isinstance(value, np.ndarray):
        if value.ndim > 1 or value.dtype.kind not in "iuf" or value.size > _MAX_NUMBERS:
            return None
        value = value.reshape(-1).tolist()
    if isinstance(value, (list, tuple)) and len(value) > _MAX_NUMBERS:
        return None                    # no validator takes more; a 10-million-number list is refused at once
    if isinstance(value, (list, tuple)) and all(_is_real(x) for x in value):
        return [_as_float(x) for x in value]
    return None


def _fmt(x) -> str:
    if isinstance(x, float) and x.is_integer() and abs(x) < 1e6:
        return str(int(x))
    return f"{x:g}" if isinstance(x, float) else str(x)


def _range(lo, hi, open_interval: bool, lead: str = "") -> str:
    """' in [lo, hi]', ' >= lo', ' <= hi' or '' (no bound)."""
    lo_inf, hi_inf = lo == -math.inf, hi == math.inf
    if lo_inf and hi_inf:
        return ""
    if hi_inf:
        return f"{lead}{'>' if open_interval else '>='} {_fmt(lo)}"
    if lo_inf:
        return f"{lead}{'<' if open_interval else '<='} {_fmt(hi)}"
    b = "()" if open_interval else "[]"
    return f"{lead}in {b[0]}{_fmt(lo)}, {_fmt(hi)}{b[1]}"


def _show(value) -> str:
    """A short one-line repr of a value for a message."""
    if isinstance(value, np.ndarray):
        if value.size > 3:
            return f"<{value.dtype} array of shape {value.shape}>"
        value = value.tolist()
    elif isinstance(value, np.generic):
        value = value.item()
    try:
        text = repr(value)
    except Exception:              # a hostile __repr__
        text = f"<{type(value).__name__}>"
    text = " ".join(text.split())
    return text if len(text) <= _SHOW_MAX else text[:_SHOW_MAX - 3] + "..."


def _error(src: str, name: str, value, what: str) -> PopvolError:
    return PopvolError(f"{src}: {name} = {_show(value)} {what}")
