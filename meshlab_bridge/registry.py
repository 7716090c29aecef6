"""
registry.py
-----------
The plugin-style filter registry.  Each filter is declared exactly once, as a
``FilterSpec`` holding its parameters (``Param``); that one declaration drives
parameter validation, MeshSet application (``apply.py``), the command line
(``cli.py``), ``print_filter_parameter_list`` and the README filter table.

Spec modules live in ``meshlab_bridge/specs/`` (one per filter family) and call
``register`` at import time.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

from filters._params import UNITS, Param, resolve_params  # noqa: F401  (re-exported)
from filters._validation import InvalidParameterError

#: how a filter's result lands in a MeshSet
KINDS = ("coord", "scalar", "selection", "new_layer", "measure")


@dataclass(frozen=True)
class FilterSpec:
    """Declaration of one filter.

    Attributes
    ----------
    name : str
        pymeshlab-style name (``apply_coord_…``, ``compute_scalar_…``,
        ``compute_selection_…``, ``generate_…``).
    command : str
        CLI sub-command (``denoise``, ``saliency``, …).
    label : str
        Short human title.
    description : str
        A paragraph citing the thesis chapter and equations.
    func : callable
        ``func(points, normals=None, **params) -> Result`` (a frozen dataclass).
    params : tuple of Param
    kind : str
        ``"coord"`` (positions/normals replaced in place; ``mask_field``, if
        set, becomes the vertex selection), ``"scalar"`` (``scalar_field`` → vertex
        quality + colour ramp), ``"selection"`` (``mask_field`` → selection,
        ``scalar_field`` → quality), ``"new_layer"`` (``index_field`` = kept
        input indices → new layer; optional ``scalar_field`` → its quality).
    requires : tuple of str
        ``("normals",)`` when the input must carry normals.
    uses_normals : bool
        Pass the layer's normals (when present) to ``func``.
    """

    name: str
    command: str
    label: str
    description: str
    func: Callable
    params: tuple[Param, ...]
    kind: str
    scalar_field: str | None = None
    mask_field: str | None = None
    index_field: str | None = None
    points_field: str = "points"
    normals_field: str | None = "normals"
    requires: tuple[str, ...] = ()
    uses_normals: bool = False
    thesis: str = ""
    extra: dict = field(default_factory=dict)

    def param(self, name: str) -> Param:
        for p in self.params:
            if p.name == name:
                return p
        raise InvalidParameterError(f"{self.name}: unknown parameter {name!r}")

    def defaults(self) -> dict:
        return {p.name: p.default for p in self.params}

    def resolve(self, params: dict) -> dict:
        """Validate ``params`` against the declaration and fill in defaults."""
        return resolve_params(self.params, params, self.name)


FILTERS: dict[str, FilterSpec] = {}


def register(spec: FilterSpec) -> FilterSpec:
    """Add ``spec`` to the registry (names and commands must be unique)."""
    if spec.kind not in KINDS:
        raise ValueError(f"register: kind must be one of {KINDS}, got {spec.kind!r}")
    if spec.name in FILTERS and FILTERS[spec.name] is not spec:
        raise ValueError(f"register: filter {spec.name!r} declared twice")
    for other in FILTERS.values():
        if other.command == spec.command and other.name != spec.name:
            raise ValueError(f"register: command {spec.command!r} declared twice")
    FILTERS[spec.name] = spec
    return spec


def load_all() -> dict[str, FilterSpec]:
    """Import every spec module (idempotent) and return the registry."""
    from . import specs  # noqa: F401  (import registers)

    return FILTERS


def get(name_or_command: str) -> FilterSpec:
    """Look a filter up by its registry name or its CLI command."""
    load_all()
    if name_or_command in FILTERS:
        return FILTERS[name_or_command]
    for spec in FILTERS.values():
        if spec.command == name_or_command:
            return spec
    raise InvalidParameterError(
        f"unknown filter {name_or_command!r}; known: {', '.join(sorted(FILTERS))}"
    )
