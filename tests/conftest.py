"""Shared fixtures: synthetic grids from the paper's model (eq. 1)."""

import numpy as np
import pytest

from gridstrain import Lattice
from gridstrain.models import synthetic

# the BLAS limit held for a worker's whole life (released with the process)
_BLAS_LIMIT = []


def pytest_configure(config):
    # Under pytest-xdist every worker is a process of its own with OpenBLAS's default
    # pool (one thread less than the cores, per copy: numpy's and scipy's): two workers
    # on 2 cores would each spin BLAS threads against the other's transforms. The
    # measurements keep BLAS on the calling thread anyway (threads.one_blas_thread);
    # the rest of a test's small products gain nothing from more.
    if hasattr(config, "workerinput"):
        import scipy.linalg  # noqa: F401  (its own OpenBLAS copy, loaded to be limited)
        from threadpoolctl import threadpool_limits

        _BLAS_LIMIT.append(threadpool_limits(limits=1, user_api="blas"))


@pytest.fixture(scope="session")
def lattice5():
    """The paper's axis-aligned grid of pitch 5 px."""
    return Lattice.from_pitch(5.0)


@pytest.fixture(scope="session")
def grid256(lattice5):
    """Noise-free 256 x 256 grid, pitch 5, line profile (1/2) sin^3."""
    return synthetic.grid_image((256, 256), lattice5)


def rigid(ux, uy):
    """A rigid translation as a Lagrangian displacement field."""
    return lambda X, Y: (ux + 0 * X, uy + 0 * Y)


@pytest.fixture
def rng():
    return np.random.default_rng(20150101)


@pytest.fixture
def spy(monkeypatch):
    """``spy(owner, name)``: the list of the first argument after ``self`` of every
    later call of method ``name`` of class ``owner``, the method still run."""
    def watch(owner, name):
        seen = []
        real = getattr(owner, name)

        def called(self, first, *args, **kwargs):
            seen.append(first)
            return real(self, first, *args, **kwargs)

        monkeypatch.setattr(owner, name, called)
        return seen
    return watch
