"""
registry.py
-----------
The plugin-style filter registry.  Each filter is declared once, as a
``FilterSpec``; its parameters come from the NumPy function itself
(``func.params``, filled by ``pcprep.filters._params.validate_params`` from the
signature, the docstring and the constraints), so the spec, MeshSet
application (``apply.py``), the command line (``cli.py``),
``print_filter_parameter_list`` and the README filter table cannot disagree.

Spec modules live in ``meshlab_bridge/specs/``, one per family of
``specs.FAMILIES``, and call ``register`` when imported.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

from pcprep.filters._params import UNITS, Param, resolve_params  # noqa: F401  (re-exported)
from pcprep.filters._validation import InvalidParameterError

#: how a filter's result lands in a MeshSet
KINDS = ("coord", "scalar", "selection", "new_layer", "remove")


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
        ``func(points, normals=None, **params) -> Result`` (a frozen dataclass),
        decorated with ``validate_params`` so that ``func.params`` exists.
    kind : str
        ``"coord"`` (positions/normals replaced; ``mask_field``, if set, becomes
        the vertex selection), ``"scalar"`` (``scalar_field`` → vertex quality and
        a colour ramp), ``"selection"`` (``mask_field`` → selection,
        ``scalar_field`` → a custom attribute), ``"new_layer"`` (``index_field`` =
        kept input indices → new layer), ``"remove"`` (``index_field`` = kept
        input indices; the other vertices are removed from the layer).
    uses_normals : bool
        Pass the layer's normals (when present) to ``func``.
    attribute : str or None
        Name of the per-point attribute (PLY property, LAS extra dimension,
        MeshSet custom attribute) that receives the filter's main per-point
        result (``mask_field`` or ``scalar_field``), e.g. ``"sharp"``; a name
        already present is never overwritten (``"sharp_2"`` is used instead).
    example : dict
        Parameters for a quick run on a few thousand points (the contract tests
        and the docs use them).
    """

    name: str
    command: str
    label: str
    description: str
    func: Callable
    kind: str
    scalar_field: str | None = None
    mask_field: str | None = None
    index_field: str | None = None
    points_field: str = "points"
    normals_field: str | None = "normals"
    uses_normals: bool = False
    attribute: str | None = None
    example: dict = field(default_factory=dict)

    @property
    def params(self) -> tuple[Param, ...]:
        return self.func.params

    def param(self, name: str) -> Param:
        for p in self.params:
            if p.name == name:
                return p
        raise InvalidParameterError(f"{self.name}: unknown parameter {name!r}")

    def defaults(self) -> dict:
        return {p.name: p.default for p in self.params}

    def resolve(self, params: dict) -> dict:
        """Validate ``params`` against the declaration and fill in defaults."""
        return resolve_params(self.params, params, self.name,
                              getattr(self.func, "presets", None))


FILTERS: dict[str, FilterSpec] = {}


def register(spec: FilterSpec) -> FilterSpec:
    """Add ``spec`` to the registry (names and commands must be unique)."""
    if not hasattr(spec.func, "params"):
        raise TypeError(f"register: {spec.name}'s function is not decorated with "
                        "validate_params")
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
