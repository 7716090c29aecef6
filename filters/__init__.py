"""pcprep filters: the algorithms, NumPy arrays in and out (no file I/O, no MeshSet).

A filter is a function ``func(points, normals=None, *, ...) -> Result`` decorated
with ``validate_params``; ``Param`` declares each keyword's constraint.
"""

from ._params import Param, resolve_params, validate_params
from ._validation import InvalidParameterError, PointCloudError
from .neighbors import average_spacing

__all__ = ["InvalidParameterError", "Param", "PointCloudError", "average_spacing",
           "resolve_params", "validate_params"]
