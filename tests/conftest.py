"""Shared pytest fixtures."""
from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture
def rng() -> np.random.Generator:
    """A seeded random generator: every test that draws numbers is reproducible."""
    return np.random.default_rng(20080205)
