"""From recordings to posteriors: priors, likelihoods, the one sampling engine, statistics (ArviZ),
the run store, the per-test calibration, the cable-law fit and the amplitude map
(``docs/calibration.md``, ``docs/cable.md``, ``docs/amplitude.md``)."""
