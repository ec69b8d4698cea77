"""Shared pytest configuration for the phc test suite.

Generated residual modules are cached on disk (:mod:`phc.codegen.load`); the tests
point that cache at a per-session temporary directory so they never touch the
user's ``~/.cache/phc`` and always start from an empty cache.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):  # as the `phc` command does
    os.environ.setdefault(_var, "1")

import pytest  # noqa: E402


@pytest.fixture(scope="session", autouse=True)
def _shipped_models_may_be_referenced():
    """Many tests write scenes into a temporary directory that name a shipped model by its
    absolute path; phc reads a scene's model only inside the scene's tree unless allowed
    (``PHC_ALLOW_PATH``), so the suite allows ``models/`` — as a user passes --allow-path."""
    models = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "models")
    previous = os.environ.get("PHC_ALLOW_PATH")
    os.environ["PHC_ALLOW_PATH"] = os.pathsep.join(p for p in (previous, models) if p)
    yield
    if previous is None:
        os.environ.pop("PHC_ALLOW_PATH", None)
    else:
        os.environ["PHC_ALLOW_PATH"] = previous


@pytest.fixture(scope="session", autouse=True)
def _isolated_phc_cache(tmp_path_factory):
    previous = {var: os.environ.get(var) for var in ("PHC_CACHE_DIR", "PHC_STATE_DIR")}
    os.environ["PHC_CACHE_DIR"] = str(tmp_path_factory.mktemp("phc-cache"))
    os.environ["PHC_STATE_DIR"] = str(tmp_path_factory.mktemp("phc-state"))  # the key signing compiled code
    yield
    for var, value in previous.items():
        if value is None:
            os.environ.pop(var, None)
        else:
            os.environ[var] = value


# The suite runs the NumPy module unless PHC_BACKEND says otherwise (PHC_BACKEND=numba python
# -m pytest runs it all on compiled code); the backend tests and the solver contract ask for
# both backends themselves (tests/codegen/test_backends.py, tests/simulation/test_backend_contract.py).
os.environ.setdefault("PHC_BACKEND", "numpy")
