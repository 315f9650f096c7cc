"""Noisy bench runs for the tests: the one way they are made from a model curve."""

import numpy as np


def noisy_runs(fuu, n_runs: int, rng: np.random.Generator, sigma_mag: float = 0.02, sigma_phase: float = 0.01):
    """``n_runs`` runs of the curve ``fuu`` (complex, ``(F,)`` or ``(1, F)``): iid noise per line in
    log-magnitude (sd ``sigma_mag``) and phase (sd ``sigma_phase`` rad), magnitude drawn first; ``(n_runs, F)``."""
    shape = (n_runs, np.shape(fuu)[-1])
    return fuu * np.exp(sigma_mag * rng.standard_normal(shape) + 1j * sigma_phase * rng.standard_normal(shape))
