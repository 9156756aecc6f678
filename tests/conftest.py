"""Shared fixtures: synthetic grids from the paper's model (eq. 1)."""

import numpy as np
import pytest

from gridstrain import Lattice
from gridstrain.models import synthetic


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
