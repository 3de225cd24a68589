from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture
def rng() -> np.random.Generator:
    """Seeded generator: a failing test reproduces."""
    return np.random.default_rng(20240611)
