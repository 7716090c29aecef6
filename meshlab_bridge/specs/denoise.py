"""
denoise.py
----------
Registry declaration of the denoising family (thesis chapter 4).
"""

from filters import denoise as _m

from ..registry import FilterSpec, register

register(FilterSpec(
    name="apply_coord_denoise_l1_tv",
    command="denoise",
    label="L1-median / L1-TV denoising",
    description=(
        "Feature-preserving denoising, thesis ch.4, eqs (4.2)-(4.19), Algorithm 4.1: per "
        "point, a robust tangent plane by an L1-median height fit with ψ, θ weights (4.3) "
        "with an L1 total-variation term on the normals (4.4), minimised by "
        "alternating a proximal-gradient normal step with soft thresholding (4.10)-(4.12) "
        "and an IRLS offset step (4.14); each point then moves onto its plane, bounded to "
        "ε = 4h from the input (4.15); edge points (normal variation V_n < th, 4.16-4.17) "
        "are snapped onto the plane across the edge (4.18)-(4.19).  Positions and normals "
        "of the current layer are replaced (same point count and order); edge points are "
        "selected.  Lengths are in units of the average spacing h."
    ),
    func=_m.denoise_l1_tv,
    params=_m.PARAMS,
    kind="coord",
    mask_field="edge_mask",
    uses_normals=True,
    thesis="ch.4, eqs (4.2)-(4.19), Algorithm 4.1",
    extra={"example": {"n_iter": 2}},
))
