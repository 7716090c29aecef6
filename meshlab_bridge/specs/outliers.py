"""
outliers.py
-----------
Registry declaration of outlier removal (not in the thesis: a cleaning step
before its filters, with PCL's statistical and radius criteria).
"""

from pcprep.filters import outliers as _m

from ..registry import FilterSpec, register

register(FilterSpec(
    name="meshing_remove_point_outliers",
    command="outliers",
    label="Remove outliers (statistical or radius)",
    description=(
        "Removes isolated points before the thesis filters (not in the thesis): the "
        "statistical criterion removes a point whose mean distance to its k nearest "
        "neighbours exceeds the mean by std_ratio standard deviations (PCL's "
        "StatisticalOutlierRemoval), the radius criterion one with fewer than "
        "min_neighbors others within radius·h (PCL's RadiusOutlierRemoval); h is the "
        "trimmed spacing, which the outliers do not move.  The layer keeps its id; "
        "the removed indices are reported."
    ),
    func=_m.remove_outliers,
    kind="remove",
    index_field="keep_idx",
))


def tile_hops(params: dict) -> int:
    """Dependency reach of outlier removal for tiled runs: 0 neighbour steps
    (a score reads only the point's own k-NN distances or radius count); the
    reach is the k-th neighbour's distance or the radius.  The statistical
    threshold (mean + std_ratio × std of every score) is cloud-wide: computed
    once from the scores of all rows."""
    return 0
