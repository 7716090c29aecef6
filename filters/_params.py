"""
_params.py
----------
Parameters declared once.  A filter's keyword-only arguments carry their default
in the signature and their meaning in the numpydoc ``Parameters`` section; the
``validate_params`` decorator adds only the constraint (kind, range, unit,
choices) and derives the rest, so the bridge, the command line and the docs read
one ``Param`` tuple (``func.params``) that cannot drift from the function.
"""

from __future__ import annotations

import ast
import functools
import inspect
import re
from dataclasses import dataclass, replace
from typing import Any, Callable

from ._validation import InvalidParameterError, check_choice, check_param

#: units a parameter may carry; lengths are always in units of h
UNITS = {
    "h": "× average spacing h",
    "deg": "degrees",
    "count": "count",
    "fraction": "fraction",
    None: "",
}

#: marks a field that ``validate_params`` fills from the function
_FROM_FUNCTION: Any = object()


@dataclass(frozen=True)
class Param:
    """The constraint on one filter parameter.

    ``kind`` is ``float``, ``int``, ``bool`` or ``str``; a ``str`` parameter with
    ``choices`` is an enumeration.  ``low``/``high``/``closed`` bound numbers
    (never clamped).  ``optional=True`` allows ``None``, meaning "resolved from
    the data at call time".  ``default`` and ``help`` are filled by
    ``validate_params`` from the signature and the docstring.
    """

    name: str
    kind: type
    low: float | None = None
    high: float | None = None
    closed: str = "both"
    unit: str | None = None
    choices: tuple = ()
    optional: bool = False
    advanced: bool = False
    default: Any = _FROM_FUNCTION
    help: str = ""

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


def resolve_params(params: tuple[Param, ...], given: dict, func: str,
                   presets: dict[str, dict] | None = None) -> dict:
    """Validate ``given`` (name → value) against ``params``; fill in defaults.

    With ``presets`` (a filter's ``.presets``) and ``given["preset"]`` set, the
    preset's values come before the defaults, as in a direct call.  Unknown
    names raise ``InvalidParameterError`` listing the known ones.  Returns a new
    dict in declaration order.
    """
    known = {p.name for p in params}
    unknown = sorted(set(given) - known)
    if unknown:
        raise InvalidParameterError(
            f"{func}: unknown parameter(s) {', '.join(map(repr, unknown))}; "
            f"known: {', '.join(sorted(known))}"
        )
    if presets and given.get("preset") is not None:
        chosen = next(p for p in params if p.name == "preset").check(given["preset"], func)
        given = {**presets[chosen], **given}
    return {p.name: p.check(given.get(p.name, p.default), func) for p in params}


_ENTRY = re.compile(r"^(\s*)(\w+(?:\s*,\s*\w+)*)\s*:\s*(.*)$")


def docstring_parameters(doc: str) -> dict[str, tuple[str, str]]:
    """``name -> (type line, description)`` from a numpydoc ``Parameters`` section."""
    lines = inspect.cleandoc(doc or "").splitlines()
    try:
        start = next(i for i, ln in enumerate(lines[:-1])
                     if ln.strip() == "Parameters" and set(lines[i + 1].strip()) == {"-"})
    except StopIteration:
        return {}
    out: dict[str, tuple[str, str]] = {}
    name = None
    body: list[str] = []
    for i in range(start + 2, len(lines)):
        ln = lines[i]
        if i + 1 < len(lines) and ln.strip() and set(lines[i + 1].strip()) == {"-"}:
            break  # the next section
        m = _ENTRY.match(ln)
        if m and not m.group(1):
            if name:
                out[name] = (out[name][0], " ".join(body).strip())
            name, body = m.group(2), []
            out[name] = (m.group(3).strip(), "")
        elif name:
            body.append(ln.strip())
    if name:
        out[name] = (out[name][0], " ".join(body).strip())
    # numpydoc's shared entry "a, b : int, default=1, 2" documents both names
    for key in [k for k in out if "," in k]:
        names = [k.strip() for k in key.split(",")]
        type_line, text = out.pop(key)
        written = _documented_default(type_line)
        values = _literal(written) if written is not None else None
        for i, nm in enumerate(names):
            line = type_line
            if isinstance(values, tuple) and len(values) == len(names):
                line = re.sub(r"default\s*=.*$", f"default={values[i]!r}", type_line)
            out[nm] = (line, text)
    return out


def _documented_default(type_line: str) -> str | None:
    m = re.search(r"default\s*=\s*(.+)$", type_line)
    return m.group(1).strip() if m else None


def _literal(text: str):
    try:
        return ast.literal_eval(text)
    except (ValueError, SyntaxError):
        return _FROM_FUNCTION  # equal to no default


#: the constraint of the ``preset`` parameter every filter with presets declares
def preset_param(presets: dict[str, dict]) -> Param:
    """``Param`` of a filter's ``preset`` argument: one of the preset names, or None."""
    return Param("preset", str, choices=tuple(presets), optional=True)


def validate_params(*constraints: Param, presets: dict[str, dict] | None = None
                    ) -> Callable:
    """Bind a filter's keyword-only parameters to their constraints.

    Every keyword-only argument of the decorated function needs exactly one
    ``Param`` and one docstring entry (``name : type, default=value``, or
    ``name : type, optional`` for a default of None, followed by its
    description); a mismatch is an error when the module is imported.
    A call binds the arguments to the signature (defaults live there), checks
    each against its ``Param`` and passes the checked values on, so unknown
    names, wrong types and out-of-range values raise ``InvalidParameterError``
    naming the function, the parameter, the allowed range and the value given.
    The filled declarations are ``wrapper.params``.

    ``presets`` maps a preset name to parameter values (e.g. ``"thesis"``: the
    method as printed).  The function then has a ``preset`` argument (declared
    with ``preset_param``); a call with ``preset=name`` takes that preset's
    values for every parameter the caller did not give, so an explicit argument
    always wins, and the function still sees ``preset`` to switch the steps
    that are not parameters.  Every preset value is checked when the module is
    imported.  The presets are ``wrapper.presets``.
    """

    def decorate(func: Callable) -> Callable:
        name = func.__name__
        sig = inspect.signature(func)
        keyword = {k: v for k, v in sig.parameters.items() if v.kind is v.KEYWORD_ONLY}
        declared = {p.name: p for p in constraints}
        if set(keyword) != set(declared):
            raise TypeError(
                f"{name}: keyword-only arguments {sorted(keyword)} and constraints "
                f"{sorted(declared)} differ")
        docs = docstring_parameters(func.__doc__)
        filled = []
        for pname in keyword:  # signature order
            if pname not in docs or not docs[pname][1]:
                raise TypeError(f"{name}: parameter {pname!r} is not documented")
            type_line, text = docs[pname]
            default = keyword[pname].default
            written = _documented_default(type_line)
            ok = _literal(written) == default if written is not None else (
                default is None and type_line.endswith("optional"))
            if not ok:
                raise TypeError(f"{name}: the docstring of {pname!r} gives its type as "
                                f"{type_line!r}; the signature's default is {default!r}")
            p = replace(declared[pname], default=default, help=text)
            p.check(default, name)  # a default outside its own range is a bug
            filled.append(p)
        params = tuple(filled)
        table = {k: dict(v) for k, v in (presets or {}).items()}
        if table and "preset" not in declared:
            raise TypeError(f"{name}: presets given but no 'preset' parameter")
        by_name = {p.name: p for p in params}
        for pname, values in table.items():
            for key, value in values.items():
                if key not in by_name or key == "preset":
                    raise TypeError(f"{name}: preset {pname!r} sets unknown {key!r}")
                by_name[key].check(value, name)

        @functools.wraps(func)
        def wrapper(*args, **kwargs):
            unknown = sorted(set(kwargs) - set(sig.parameters))
            if unknown:
                raise InvalidParameterError(
                    f"{name}: unknown parameter(s) {', '.join(map(repr, unknown))}; "
                    f"known: {', '.join(sorted(keyword))}")
            try:
                bound = sig.bind(*args, **kwargs)
            except TypeError as exc:
                raise InvalidParameterError(f"{name}: {exc}") from None
            chosen = bound.arguments.get("preset")
            if chosen is not None and table:
                chosen = by_name["preset"].check(chosen, name)
                for key, value in table[chosen].items():
                    bound.arguments.setdefault(key, value)
            bound.apply_defaults()
            for p in params:
                bound.arguments[p.name] = p.check(bound.arguments[p.name], name)
            return func(*bound.args, **bound.kwargs)

        wrapper.params = params
        wrapper.presets = table
        return wrapper

    return decorate
