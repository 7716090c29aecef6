"""Filter declarations, one module per filter family.

``FAMILIES`` is the one list of families: importing this package registers every
family's filters, ``pcprep bench`` offers one benchmark per family and the report
has one section per family, in this order.  A spec module that fails to import
is an error.
"""

from importlib import import_module

#: the filter families, in the order the report presents them
FAMILIES = ("outliers", "denoise", "simplify", "features", "saliency")

for _name in FAMILIES:
    import_module(f"{__name__}.{_name}")
