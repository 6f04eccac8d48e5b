"""Java value formatting and parsing, as rddlsim does it on the wire.

rddlsim writes every number with Java's ``String.valueOf``: doubles as
``Double.toString`` (always a point or an exponent: ``10.0``, ``1.0E-4``), ints and longs
plainly. It reads values with ``Boolean.valueOf``, ``Integer.valueOf`` and
``Double.valueOf``, whose quirks (``"yes"`` is false, ``" 1"`` is not an int, ``" 1.0 "``
is a double) matter for a compatible peer, so they are reproduced here.
"""

from __future__ import annotations

import math
import re
from decimal import ROUND_HALF_EVEN, Context, Decimal
from typing import Final

from .messages import FluentValue

__all__ = [
    "VALUE_KINDS",
    "format_value",
    "java_double",
    "parse_java_double",
    "parse_java_int",
    "parse_value",
]

#: The ``kind`` values :func:`parse_value` understands.
VALUE_KINDS: Final = frozenset({"bool", "int", "real", "enum", "object"})

_INT32 = (-(2**31), 2**31 - 1)
_INT64 = (-(2**63), 2**63 - 1)

# Double.valueOf grammar after trimming (FloatingDecimal.readJavaFormatString):
# decimal digits are ASCII only, an optional float/double suffix, hex needs its exponent.
_JAVA_DECIMAL = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?[fFdD]?")
_JAVA_HEX = re.compile(
    r"([+-]?)0[xX]((?:[0-9a-fA-F]+\.?|[0-9a-fA-F]*\.[0-9a-fA-F]+)[pP][+-]?[0-9]+)[fFdD]?"
)
_JAVA_SPECIAL = {
    "NaN": math.nan,
    "+NaN": math.nan,
    "-NaN": math.nan,
    "Infinity": math.inf,
    "+Infinity": math.inf,
    "-Infinity": -math.inf,
}


def _java_trim(text: str) -> str:
    """``String.trim``: strip every char <= U+0020 (controls included, NBSP not)."""
    start, end = 0, len(text)
    while start < end and text[start] <= " ":
        start += 1
    while end > start and text[end - 1] <= " ":
        end -= 1
    return text[start:end]


def _shortest_digits(x: float) -> tuple[str, int]:
    """Digits and decimal exponent of the decimal Java prints for finite, non-zero ``x``.

    Returns ``(digits, e)`` with ``x ~= 0.d1d2... * 10**e`` shifted so that the value is
    ``d1.d2d3... * 10**e``. Python's ``repr`` gives the shortest decimal that reads back as
    ``x``, and among those the closest, which is Java's choice (JDK 19+ ``Double.toString``)
    except that Java never settles for one digit: it then takes the closest two-digit
    decimal (``4.9E-324``, not ``5e-324``).
    """
    sign_digits_exp = Decimal(repr(abs(x))).as_tuple()
    digits = "".join(str(d) for d in sign_digits_exp.digits).lstrip("0")
    exp = int(sign_digits_exp.exponent)
    stripped = digits.rstrip("0")
    exp += len(digits) - len(stripped)
    digits = stripped
    sci = exp + len(digits) - 1
    if len(digits) == 1:
        # Closest two-digit decimal to the exact binary value; it reads back as x whenever
        # the one-digit one does, except at the edges of the range, where we keep d.0.
        two = Context(prec=2, rounding=ROUND_HALF_EVEN).plus(Decimal(abs(x)))
        two_digits = "".join(str(d) for d in two.as_tuple().digits)
        two_exp = int(two.as_tuple().exponent)
        if float(two) == abs(x) and len(two_digits) == 2:
            two_sci = two_exp + 1
            if two_digits[1] == "0":
                return two_digits[0], two_sci
            return two_digits, two_sci
    return digits, sci


def java_double(x: float) -> str:
    """Java's ``Double.toString(x)``.

    Plain notation for ``1e-3 <= |x| < 1e7`` (``10.0``, ``0.001``, ``9999999.0``),
    otherwise ``d.dddE<n>`` without a ``+`` (``1.0E7``, ``1.0E-4``, ``-3.5E-5``); ``NaN``,
    ``Infinity``, ``-Infinity``, ``-0.0``. The digits are the shortest that read back as
    ``x`` (JDK 19+; JDK 17 and older print a longer string for a few values such as
    ``2.0E23``).
    """
    x = float(x)
    if math.isnan(x):
        return "NaN"
    if math.isinf(x):
        return "Infinity" if x > 0 else "-Infinity"
    if x == 0.0:
        return "-0.0" if math.copysign(1.0, x) < 0 else "0.0"
    if 1e-3 <= abs(x) < 1e7:
        # Here Python's repr is plain notation with the same shortest digits
        # (a one-digit value cannot have a closer two-digit neighbour at 53 bits).
        return repr(x)
    sign = "-" if x < 0 else ""
    digits, sci = _shortest_digits(x)
    if 1e-3 <= abs(x) < 1e7:
        if sci >= 0:
            whole = digits[: sci + 1].ljust(sci + 1, "0")
            frac = digits[sci + 1 :] or "0"
        else:
            whole = "0"
            frac = "0" * (-sci - 1) + digits
        return f"{sign}{whole}.{frac}"
    return f"{sign}{digits[0]}.{digits[1:] or '0'}E{sci}"


def _unwrap_numpy(v: object) -> object:
    # numpy scalars (np.bool_, np.int64, np.float32, ...) without importing numpy: they
    # all live in the numpy module and convert to the Python scalar with .item().
    if type(v).__module__ == "numpy" and hasattr(v, "item"):
        return v.item()
    return v


def format_value(v: FluentValue | object) -> str:
    """A fluent or action value as rddlsim writes it.

    ``bool`` -> ``true``/``false``; ``int`` -> decimal (no ``.0``); ``float`` ->
    :func:`java_double`; ``str`` (enum ``@x`` or object name) as is. numpy scalars are
    treated like the Python scalar they stand for.
    """
    v = _unwrap_numpy(v)
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return java_double(v)
    if isinstance(v, str):
        return v
    raise TypeError(f"cannot format {type(v).__name__} value {v!r} as a fluent value")


def parse_java_int(text: str, *, bits: int = 32) -> int:
    """``Integer.valueOf`` (``bits=32``) or ``Long.valueOf`` (``bits=64``).

    An optional sign, then decimal digits only; no whitespace, no ``.0``; the value must
    fit the width. Raises ``ValueError`` otherwise.
    """
    body = text[1:] if text[:1] in ("+", "-") else text
    # str.isdecimal matches Java's Character.digit(c, 10) (Unicode Nd digits).
    if not body or not body.isdecimal():
        raise ValueError(f"not a Java {'int' if bits == 32 else 'long'}: {text!r}")
    value = int(text)
    low, high = _INT32 if bits == 32 else _INT64
    if not low <= value <= high:
        raise ValueError(f"out of range for a Java {'int' if bits == 32 else 'long'}: {text!r}")
    return value


def parse_java_double(text: str) -> float:
    """``Double.valueOf``: trims chars <= U+0020, accepts ``1``, ``.25``, ``1.``,
    ``1.0E-3``, ``1e3``, a trailing ``d``/``f``/``D``/``F``, hex ``0x1.8p1``, ``NaN`` and
    ``[+-]Infinity``. Raises ``ValueError`` for anything else (``inf``, ``1_0``, ``""``).
    """
    s = _java_trim(text)
    special = _JAVA_SPECIAL.get(s)
    if special is not None:
        return special
    if _JAVA_DECIMAL.fullmatch(s):
        if s[-1] in "fFdD":
            s = s[:-1]
        return float(s)
    m = _JAVA_HEX.fullmatch(s)
    if m:
        try:
            value = float.fromhex("0x" + m.group(2))
        except OverflowError:
            value = math.inf
        return -value if m.group(1) == "-" else value
    raise ValueError(f"not a Java double: {text!r}")


def parse_value(text: str, kind: str) -> FluentValue:
    """Interpret the raw text of a fluent or action value the way rddlsim does.

    ``kind`` is the declared range: ``bool`` (``Boolean.valueOf``: true iff the text is
    ``true`` in any case, so ``yes``, ``1`` and `` true `` are false), ``int``
    (:func:`parse_java_int`), ``real`` (:func:`parse_java_double`), ``enum`` / ``object``
    (the text as is). Raises ``ValueError`` for unparsable numbers or an unknown kind.
    """
    if kind == "bool":
        return text.lower() == "true"
    if kind == "int":
        return parse_java_int(text)
    if kind == "real":
        return parse_java_double(text)
    if kind in ("enum", "object"):
        return text
    raise ValueError(f"unknown value kind {kind!r}; expected one of {sorted(VALUE_KINDS)}")
