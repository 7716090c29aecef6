"""pcprep filters: pure NumPy/SciPy/scikit-learn algorithms, arrays in and out."""

from ._validation import InvalidParameterError, PointCloudError
from .neighbors import average_spacing

__all__ = ["InvalidParameterError", "PointCloudError", "average_spacing"]
