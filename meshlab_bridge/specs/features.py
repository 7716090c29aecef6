"""
features.py
-----------
Registry declaration of the feature-detection family (thesis chapter 7):
sharp features and hole boundaries.
"""

from pcprep.filters import features as _m

from ..registry import FilterSpec, register

register(FilterSpec(
    name="compute_selection_sharp_features_sparse",
    command="features",
    label="Sharp features by K-SVD code length",
    description=(
        "Selects points on sharp features (edges, corners), thesis ch.7, eqs (7.1)-(7.11) "
        "and §7.3.5: weighted-PCA features (λ0, λ0/λ2, surface variation, projected "
        "distance) at 10 neighbourhood sizes from one sorted k-NN query, standardised and "
        "concatenated; a K-SVD dictionary of S = 100 atoms; each point's code length "
        "(ℓ1 size of its code plus residual; the atom count of (7.8) with score='count') "
        "thresholded automatically by Otsu's method, or at β·max (7.10); then a "
        "localisation step (not in the thesis; crease_width, empty = off) keeps the points "
        "within crease_width·h of the crease line estimated from their neighbourhood, "
        "narrowing the detected band to the edge.  Detected points become the vertex "
        "selection and vertex quality 1 (others 0); the code-length score is kept as the "
        "per-vertex attribute 'score'."
    ),
    func=_m.detect_sharp_features,
    kind="selection",
    mask_field="mask",
    scalar_field="score",
    uses_normals=False,
    example={"seed": 0},
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
        "Otsu (applied twice, rims being rare) or at β·max; a geometric gate (min_shift) "
        "and a localisation step (not in the thesis; rim_width, empty = off) keeping the "
        "points whose border distance, from the half-disc centroid-shift law, is at most "
        "rim_width·h.  The printed rule (7.12)-(7.13), f < β·min f, selects nothing; see "
        "the filter's documentation.  Detected points become the vertex selection and "
        "vertex quality 1 (others 0)."
    ),
    func=_m.detect_hole_boundaries,
    kind="selection",
    mask_field="mask",
    scalar_field="score",
    uses_normals=False,
    example={"seed": 0},
))
