"""From recordings to posteriors: priors, likelihoods, the one sampling engine, statistics (ArviZ),
the run store, the per-test calibration, the cable-law fit and the amplitude map
(``docs/calibration.md``, ``docs/cable.md``, ``docs/amplitude.md``)."""

from ..core.lazy import lazy_exports

_LAZY = {
    "Prior": ".priors", "load_prior": ".priors", "cable_prior": ".priors",
    "SamplerConfig": ".sampler", "SampleResult": ".sampler", "sample": ".sampler",
    "calibrate_test": ".calibrate", "fit_check": ".fitcheck", "read_run": ".runs", "read_summary": ".runs",
    "amplitude_map": ".amplitude", "fit_cable": ".cable_fit", "store_cable": ".cable_fit",
    "read_cable": ".cable_fit", "fit_population": ".batch", "read_batch": ".batch",
}
__getattr__, __dir__ = lazy_exports(__name__, _LAZY)
__all__ = sorted(_LAZY)
