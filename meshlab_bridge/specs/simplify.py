"""
simplify.py
-----------
Registry declaration of the simplification family (thesis chapter 6).
"""

from pcprep.filters import simplify as _m

from ..registry import FilterSpec, register

register(FilterSpec(
    name="generate_simplified_point_cloud_sdbs",
    command="simplify",
    label="Saliency-dictionary simplification (SDBS)",
    description=(
        "Feature-preserving simplification, thesis ch.6 §6.3, eqs (6.1)-(6.11): per-point "
        "features F = (normal, surface variation σ, position) from weighted PCA (6.1)-(6.4), "
        "a K-SVD dictionary of S atoms (Alg. 3.3) and Lasso codes by LARS (3.7); the "
        "saliency Sf = normalised ‖α‖₀ × normalised residual ‖F − Dα‖₂ (6.5)-(6.10) sets a "
        "removal radius ρ_i = δ/Sf_i (6.11), and points visited by decreasing Sf remove "
        "their unvisited neighbours within ρ_i.  Give exactly one of ratio, count (δ is "
        "searched, the count is then made exact) or delta (in units of h).  The kept input "
        "points, with all their attributes, form a new layer (as MeshLab's "
        "generate_simplified_point_cloud does); their saliency Sf is its quality."
    ),
    func=_m.simplify_sdbs,
    kind="new_layer",
    index_field="keep_idx",
    scalar_field="score",
    uses_normals=True,
    example={"ratio": 0.1},
))
