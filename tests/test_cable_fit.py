"""The joint cable fit: where its posterior is sampled from."""

import numpy as np

from sbcal.data.clean_bench import clean_bench
from sbcal.data.readers import default_bench_path, load_bench
from sbcal.data.labels import state_tests
from sbcal.inference.cable_fit import cable_likelihood, cable_start, compared_laws
from sbcal.model.hysteresis import FITTED_LAWS

# Where the engine's own start (one differential-evolution search, seed 1) stopped on damper1's dry
# cable under iwan5: chi_macro on its bound, a plateau where the law no longer changes within the
# bench's curvatures; two of four ensembles stayed there (R-hat 1.5 after 1500 steps).
PLATEAU = {"a1": 0.028022, "a2": -0.015354, "EJ_min": 3.3551, "beta_material": 0.14786, "chi_macro": 0.99999,
           "chi_micro": 0.0023877, "delta_EJ": 33.783, "density_exponent": -1.40546, "macro_ratio": 0.004559}


def test_the_cable_start_finds_the_mode_not_the_plateau(damper1):
    bench = clean_bench(load_bench(default_bench_path()), dampers=["damper1"])
    like = cable_likelihood(damper1, bench, state_tests(bench.tests("damper1"))["dry"], "iwan5")
    z = cable_start(like, np.random.default_rng(0))
    params = dict(zip(like.prior.names, like.prior.to_natural(z[None])[0]))
    # the mode: chi_macro 0.269 (0.260-0.278, 90 % of the posterior), 720 above the plateau in
    # log-posterior; the start (measured 711 above with seeds 0-2) need only be in its basin
    assert 0.2 < params["chi_macro"] < 0.35
    assert like(z[None])[0] > like(like.prior.z_of(PLATEAU))[0] + 500


def test_a_tail_is_compared_only_where_every_state_has_two_tests():
    """iwan_tail needs two amplitudes per cable state (one does not identify its tail); the others one."""
    assert compared_laws(FITTED_LAWS, ["1-1", "2-2"]) == ("bouc_wen", "iwan5", "iwan_tail")
    assert compared_laws(FITTED_LAWS, ["0.5-0.5", "1-1", "2-2", "1-1-oiled"]) == ("bouc_wen", "iwan5")
    assert compared_laws(FITTED_LAWS, ["1-1"]) == ("bouc_wen", "iwan5")
