"""Filter declarations, one module per filter family.

Importing this package registers every filter whose module imports cleanly.
"""

from importlib import import_module

_MODULES = ("denoise", "simplify", "features", "saliency")

for _name in _MODULES:
    try:
        import_module(f"{__name__}.{_name}")
    except ModuleNotFoundError as exc:  # a family not yet written
        if exc.name != f"{__name__}.{_name}":
            raise
