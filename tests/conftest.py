import numpy as np
import pytest


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture(params=["compiled", "numpy"])
def solver_path(request, monkeypatch):
    """Run a test once with the compiled kernels (numba) and once with the
    NumPy reference implementations; both must give the same answers."""
    from pcprep.filters import _kernels

    if request.param == "compiled" and not _kernels.HAVE_NUMBA:
        pytest.skip("numba not installed")
    monkeypatch.setattr(_kernels, "ENABLED", request.param == "compiled")
    return request.param
