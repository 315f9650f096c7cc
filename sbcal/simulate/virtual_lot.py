"""A virtual production lot: units of one design drawn from a known population, each on the virtual bench.

Every unit is the damper of :mod:`sbcal.simulate.virtual_bench` with its own cable: its rigidity
(``EJ``, and with strand slip the stuck part ``delta_EJ`` with it), its loss factor and, with strand slip,
the slip law's curvature scale are the design's values times lognormal factors of the lot's scatter. One
unit may be planted off the population: its rigidity a fixed fraction from the design's (not a draw).
The bench's own re-clamping scatter, noise and outlier runs come on top, as for any recording.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from ..core.errors import InputError
from ..model.damper import Damper
from .virtual_bench import BenchConfig, SlipLaw, record


__all__ = ["LotConfig", "unit_name", "record_lot"]


@dataclass(frozen=True)
class LotConfig:
    """The lot's population.

    Attributes
    ----------
    units : int
    ej_scatter, beta_scatter, slip_scatter : float
        Standard deviations of the units' log factors on the cable rigidity, the loss factor and the slip
        law's curvature scale (0.05: about 5 %).
    outlier : int or None
        Index of the planted unit (0-based), or None.
    outlier_ej : float
        The planted unit's rigidity relative to the design's: ``EJ (1 + outlier_ej)``.
    bench : BenchConfig
        The design's values (``params``, ``effects``) and the bench's artefacts.
    """

    units: int = 12
    ej_scatter: float = 0.05
    beta_scatter: float = 0.10
    slip_scatter: float = 0.10
    outlier: int | None = None
    outlier_ej: float = -0.15
    bench: BenchConfig = BenchConfig(runs=10)

    def __post_init__(self):
        if self.units < 1:
            raise InputError(f"units: expected >= 1, got {self.units}")
        if self.outlier is not None and not 0 <= self.outlier < self.units:
            raise InputError(f"outlier: unit index {self.outlier} outside 0..{self.units - 1}")


def unit_name(damper: Damper, k: int) -> str:
    """The ``k``-th unit's name (0-based ``k``): ``damper1-u01``."""
    return f"{damper.name}-u{k + 1:02d}"


def record_lot(damper: Damper, config: LotConfig, tests, *, rng: np.random.Generator) -> tuple[pd.DataFrame, dict]:
    """Record every unit of a lot on the virtual bench.

    Returns
    -------
    frame : DataFrame
        Bench CSV rows, the ``damper`` column each unit's name (:func:`unit_name`).
    truth : dict
        Unit name -> its factors ``{"EJ": f, "beta": f, "slip": f}`` and ``outlier`` (bool).
    """
    base = dict(config.bench.params)
    ej = float(base.get("EJ", 0.1 * damper.ej_static))
    beta = float(base.get("beta", 0.3))
    slip = config.bench.effects.get("strand_slip")
    frames, truth = [], {}
    for k in range(config.units):
        z = rng.standard_normal(3)
        f_ej, f_beta, f_slip = np.exp(z * (config.ej_scatter, config.beta_scatter, config.slip_scatter))
        planted = config.outlier == k
        if planted:
            f_ej = 1.0 + config.outlier_ej
        effects = dict(config.bench.effects)
        if isinstance(slip, SlipLaw):
            lp = slip.law_params(ej, damper.ej_static)
            lp["delta_EJ"] = float(lp["delta_EJ"]) * f_ej
            lp[slip.scale_name] = float(lp[slip.scale_name]) * f_slip
            effects["strand_slip"] = replace(slip, params=tuple(sorted(lp.items())))
        unit = replace(damper, name=unit_name(damper, k))
        cfg = replace(config.bench, params={**base, "EJ": ej * f_ej, "beta": beta * f_beta}, effects=effects)
        frames.append(record(unit, cfg, tests, rng=rng))
        truth[unit.name] = {"EJ": float(f_ej), "beta": float(f_beta), "slip": float(f_slip), "outlier": planted}
    return pd.concat(frames, ignore_index=True), truth
