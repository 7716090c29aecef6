"""pcprep filters: the algorithms, NumPy arrays in and out (no file I/O, no MeshSet).

A filter is a function ``func(points, normals=None, *, ...) -> Result`` decorated
with ``validate_params``; ``Param`` declares each keyword's constraint.
"""

from ._params import Param, docstring_parameters, resolve_params, validate_params
from ._validation import (InvalidParameterError, PointCloudError, as_normals, as_points,
                          check_param, check_spread)
from .neighbors import average_spacing

__all__ = ["InvalidParameterError", "Param", "PointCloudError", "as_normals", "as_points",
           "average_spacing", "check_param", "check_spread", "docstring_parameters",
           "resolve_params", "validate_params"]
