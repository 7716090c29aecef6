"""
saliency.py
-----------
Registry declaration of the saliency family (thesis chapter 5).
"""

from pcprep.filters import saliency as _m

from ..registry import FilterSpec, register

register(FilterSpec(
    name="compute_scalar_saliency_sparse_mdl",
    command="saliency",
    label="Saliency by local sparse coding (MDL)",
    description=(
        "Per-point saliency in [0, 1] by local sparse coding and the Minimum Description "
        "Length principle, thesis ch.5, eqs (5.2)-(5.7): each neighbourhood's mean "
        "descriptor (oriented normal, Gaussian curvature of a local quadric, global "
        "distinctness d) is Lasso-coded (λ = 0.9) against the descriptors of the "
        "neighbourhoods at the ends of rays cast in its tangent plane; the code's "
        "residual (and, with measure='mdl', its sparsity ‖α‖₀) is accumulated over the "
        "overlapping neighbourhoods that contain each point (their mean, as in the "
        "thesis, or their 10 % quantile with accumulation='quantile').  Written to "
        "vertex quality with a colour ramp, like "
        "MeshLab's curvature filters."
    ),
    attribute="saliency",
    func=_m.saliency_sparse_mdl,
    kind="scalar",
    scalar_field="saliency",
    uses_normals=True,
))


def tile_hops(params: dict) -> int:
    """Dependency reach of saliency for tiled runs, in neighbour steps
    (``pcprep.filters.saliency.SALIENCY_HOPS`` = 4): the accumulation reads the
    S_T of the neighbourhood, S_T the F̄ of the atoms (neighbours), F̄ the mean F
    of a neighbourhood and the mean d, d the F̄⁴ of a neighbourhood.  One step
    spans the k_max-th neighbour, at least the radius r (3 h).  F̄_g and the
    normalising maxima are cloud-wide: fitted in a pass of sums, broadcast."""
    from pcprep.filters.saliency import SALIENCY_HOPS

    return SALIENCY_HOPS
