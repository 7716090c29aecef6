"""
features.py
-----------
Registry declaration of the feature-detection family (thesis chapter 7):
sharp features and hole boundaries.
"""

from pcprep.filters import holes as _holes
from pcprep.filters import sharp as _sharp

from ..registry import FilterSpec, register

register(FilterSpec(
    name="compute_selection_sharp_features_sparse",
    command="features",
    label="Sharp features by K-SVD code length",
    description=(
        "Selects points on sharp features (edges, corners), thesis ch.7, eqs "
        "(7.1)-(7.11) and §7.3.5: covariance features (λ0, λ0/λ2, surface variation, "
        "projected distance) at 10 neighbourhood sizes from one sorted k-NN query, "
        "standardised and concatenated; a K-SVD dictionary of S = 100 atoms; each "
        "point's code length "
        "(ℓ1 size of its code plus residual; the atom count of (7.8) with score='count') "
        "thresholded automatically by Otsu's method, or at β·max (7.10).  Not in the "
        "thesis: a crease-angle gate (min_angle) and a localisation step that keeps the "
        "points within crease_width·h of the crease line estimated from their "
        "neighbourhood (plane_width where two fitted planes explain it), the same "
        "widths on every sampling.  Detected points become the vertex selection and vertex "
        "quality 1 (others 0); the code-length score is kept as the per-vertex "
        "attribute 'score'."
    ),
    attribute="sharp",
    func=_sharp.detect_sharp_features,
    kind="selection",
    mask_field="mask",
    scalar_field="score",
    uses_normals=False,
))

register(FilterSpec(
    name="compute_selection_hole_boundaries_sparse",
    command="holes",
    label="Hole boundaries by K-SVD code rarity",
    description=(
        "Selects points on hole rims and open borders, thesis ch.7, eqs (7.5)-(7.7) and "
        "§7.3.4: border features (|λ2 − 2λ1|/λ2, local density k/(πr²), tangential "
        "centroid shift) at 10 neighbourhood sizes, oriented and robustly standardised; "
        "K-SVD with S = 100 atoms; rarity = ℓ1 size of each point's code, thresholded by "
        "Otsu or at β·max.  Not in the thesis: a shift gate (min_shift), the border "
        "distance (rim_width) and the extent to the outermost samples (extent_width), a "
        "flatness gate (max_variation), border support (min_support), the smallest hole "
        "on random-like sampling (min_radius) and the border row on mesh-like sampling "
        "(row_angle).  The printed rule (7.12)-(7.13), f < β·min f, selects nothing; see "
        "the filter's documentation.  Detected points become the vertex selection and "
        "vertex quality 1 (others 0)."
    ),
    attribute="hole",
    func=_holes.detect_hole_boundaries,
    kind="selection",
    mask_field="mask",
    scalar_field="score",
    uses_normals=False,
))
