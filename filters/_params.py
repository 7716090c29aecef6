"""
_params.py
----------
Parameter declarations.  Each filter module declares its parameters once, as a
tuple ``PARAMS`` of ``Param``; the NumPy function validates its keyword
arguments with ``resolve_params`` and the MeshLab bridge, the CLI and the docs
read the same tuple.  Lengths are always in units of h.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from ._validation import InvalidParameterError, check_choice, check_param

#: units a parameter may carry; lengths are always in units of h
UNITS = {
    "h": "× average spacing h",
    "deg": "degrees",
    "count": "count",
    "fraction": "fraction",
    None: "",
}

@dataclass(frozen=True)
class Param:
    """One filter parameter.

    ``kind`` is one of ``float``, ``int``, ``bool``, ``str``; a ``str`` parameter
    with ``choices`` is an enumeration.  ``low``/``high``/``closed`` bound
    numbers (never clamped).  ``default=None`` with ``optional=True`` means
    "resolved from the data at call time".
    """

    name: str
    kind: type
    default: Any
    help: str
    low: float | None = None
    high: float | None = None
    closed: str = "both"
    unit: str | None = None
    choices: tuple = ()
    optional: bool = False
    advanced: bool = False

    def check(self, value, func: str):
        if value is None and self.optional:
            return None
        if self.choices:
            return check_choice(value, func=func, name=self.name, choices=self.choices)
        return check_param(value, func=func, name=self.name, kind=self.kind, low=self.low,
                           high=self.high, closed=self.closed, unit=UNITS.get(self.unit) or None)

    def range_text(self) -> str:
        if self.choices:
            return " | ".join(str(c) for c in self.choices)
        if self.low is None and self.high is None:
            return ""
        lb = "[" if self.closed in ("both", "left") else "("
        rb = "]" if self.closed in ("both", "right") else ")"
        lo = "-inf" if self.low is None else f"{self.low:g}"
        hi = "inf" if self.high is None else f"{self.high:g}"
        return f"{lb}{lo}, {hi}{rb}"


def resolve_params(params: tuple[Param, ...], given: dict, func: str) -> dict:
    """Validate ``given`` (name → value) against ``params``; fill in defaults.

    Unknown names raise ``InvalidParameterError`` listing the known ones.
    Returns a new dict in declaration order.
    """
    known = {p.name for p in params}
    unknown = sorted(set(given) - known)
    if unknown:
        raise InvalidParameterError(
            f"{func}: unknown parameter(s) {', '.join(map(repr, unknown))}; "
            f"known: {', '.join(sorted(known))}"
        )
    return {p.name: p.check(given.get(p.name, p.default), func) for p in params}
