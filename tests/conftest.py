import numpy as np
import pytest

import sbcal
from sbcal.model.damper import Damper, resolve_damper
from tests.benches import noisy_runs


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


@pytest.fixture(scope="session")
def run_store(tmp_path_factory):
    """damper1 at four amplitudes (EJ falling with amplitude), three sampled fast and mapped, one left
    unsampled: the store the report and browser tests read (built once: ~40 s)."""
    import pandas as pd

    from sbcal.data.bench import curves_to_frame, write_bench
    from sbcal.data.readers import load_bench
    from sbcal.inference.sampler import SamplerConfig
    from sbcal.pipeline import Settings, clean, map_damper, sample_tests

    tmp = tmp_path_factory.mktemp("store")
    d = resolve_damper("damper1")
    rng = np.random.default_rng(77)
    frames = []
    for amp, ej, beta in ((0.2, 20.0, 0.25), (0.5, 12.0, 0.3), (1.0, 9.0, 0.33), (2.0, 7.0, 0.35)):
        fuu = sbcal.dynamic_stiffness(d, GRID, EJ=ej, beta=beta)
        noisy = noisy_runs(fuu, 6, rng)
        frames.append(curves_to_frame("damper1", f"{amp:g}-{amp:g}", GRID, amp, noisy))
    path = tmp / "bench.csv"
    write_bench(pd.concat(frames), path)
    runs = tmp / "runs"
    settings = Settings(seed=3, sampler=SamplerConfig(nwalkers=16, max_draws=150, de_population=30, de_generations=60),
                        workers=2)
    data = clean(load_bench(path), [d], store=runs, settings=settings)
    sample_tests(data, [(d, t) for t in ("0.2-0.2", "0.5-0.5", "1-1")], store=runs, settings=settings, progress=False)
    map_damper(runs, "damper1", settings=settings)
    return runs
