import numpy as np
import pytest

import sbcal
from sbcal.model.damper import Damper, resolve_damper


@pytest.fixture(scope="session")
def damper1() -> Damper:
    return resolve_damper("damper1")


@pytest.fixture(scope="session")
def other_damper() -> Damper:
    """A geometry unlike the bundled dampers (longer arms, lighter masses, a clamp offset)."""
    return Damper(name="other", m1=2.2, J1=0.011, a1=0.021, m2=1.7, J2=0.006, a2=-0.019,
                  mc=0.8, Jc=0.0011, ac=0.004, L1=0.26, L2=0.19, mu=0.41, ej_static=90.0)


@pytest.fixture
def rng():
    return np.random.default_rng(20261121)


GRID = sbcal.STANDARD_GRID_HZ
