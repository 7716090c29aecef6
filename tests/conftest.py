import numpy as np
import pytest


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


def sphere_points(n, seed=0, radius=1.0):
    g = np.random.default_rng(seed)
    p = g.normal(size=(n, 3))
    p /= np.linalg.norm(p, axis=1)[:, None]
    return radius * p


def random_rotation(seed=0):
    g = np.random.default_rng(seed)
    q, r = np.linalg.qr(g.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


@pytest.fixture(params=["compiled", "numpy"])
def solver_path(request, monkeypatch):
    """Run a test once with the compiled kernels (numba) and once with the
    NumPy reference implementations; both must give the same answers."""
    from filters import _kernels

    if request.param == "compiled" and not _kernels.HAVE_NUMBA:
        pytest.skip("numba not installed")
    monkeypatch.setattr(_kernels, "ENABLED", request.param == "compiled")
    return request.param
