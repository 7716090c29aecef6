"""
denoise.py
----------
Registry declaration of the denoising family (thesis chapter 4).
"""

from pcprep.filters import denoise as _m

from ..registry import FilterSpec, register

register(FilterSpec(
    name="apply_coord_denoise_l1_tv",
    command="denoise",
    label="L1-median / L1-TV denoising",
    description=(
        "Feature-preserving denoising, thesis ch.4, eqs (4.2)-(4.19), Algorithm 4.1: "
        "per point, a robust tangent plane by an L1-median height fit with psi and "
        "theta weights (4.3) plus an L1 total-variation term on the normals (4.4), "
        "minimised by alternating a proximal-gradient normal step with soft "
        "thresholding (4.10)-(4.12) and an IRLS offset step (4.14); each point then "
        "moves onto its plane, at most 4h from the input (4.15).  Edge points "
        "(normal variation V_n < th, 4.16-4.17) are selected; their correction onto "
        "the plane across the edge (4.18)-(4.19) is optional.  Positions and "
        "normals of the current layer are replaced (same point count and order).  "
        "Lengths are in units of the average spacing h."
    ),
    attribute="edge",
    func=_m.denoise_l1_tv,
    kind="coord",
    mask_field="edge_mask",
    uses_normals=True,
    example={"n_iter": 2},
))


def tile_hops(params: dict) -> int:
    """Dependency reach of denoise for tiled runs (meshlab_bridge/tiles.py), in
    neighbour steps: how many times a point's result reads its neighbours'
    intermediate values (``pcprep.filters.denoise.denoise_hops``: the candidate
    selection of n⁰, ``inner_iter + 1`` inner passes, the curvature smoothing
    and the optional edge correction per outer iteration, the final projection;
    26 with the defaults).  One step spans at most a point's k_max-th neighbour
    (about 3-4 h on a surface), so the halo starts at 26 × 4 h ≈ 100 h and the
    tile itself checks that it was wide enough.  The normals' MST orientation is
    not local: tiles are oriented within themselves and then made to agree."""
    from pcprep.filters.denoise import denoise_hops

    return denoise_hops(params)
