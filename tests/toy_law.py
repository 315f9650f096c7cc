"""A strand-slip law of one Jenkins element: every wire slips at the same curvature."""
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from sbcal.model.laws import register
from sbcal.model.laws.base import DELTA_EJ, HysteresisLaw, LawParameter, jenkins_rigidity, masing_loop


@register
@dataclass(frozen=True)
class JenkinsLaw(HysteresisLaw):
    """One spring (``delta_EJ``) in series with one slider that slips at ``chi_stick``."""

    name: ClassVar[str] = "jenkins"
    parameters: ClassVar[tuple] = (
        DELTA_EJ,  # its unit, domain and prior box are every law's
        LawParameter("chi_stick", "1/m", "curvature at which every wire slips", prior=("loguniform", 1e-5, 1.0)),
    )
    fitted: ClassVar[bool] = True  # sbcal cable fits it (with --law jenkins, and in --law best)
    summary: ClassVar[str] = "one Jenkins element, a sharp knee"
    scale: ClassVar[str] = "chi_stick"  # what the virtual bench's strand_slip value sets

    def _rigidity(self, chi, *, delta_EJ, chi_stick):  # the first harmonic: the Jenkins element's
        with np.errstate(divide="ignore"):
            return delta_EJ * jenkins_rigidity(chi_stick / chi)

    def backbone(self, chi, *, delta_EJ, chi_stick):  # a Masing law: loops and time steps follow from it
        return delta_EJ * np.clip(chi, -chi_stick, chi_stick)

    def steady_loop(self, chi_a, theta, *, delta_EJ, chi_stick):
        return masing_loop(lambda x: self.backbone(x, delta_EJ=delta_EJ, chi_stick=chi_stick), chi_a, theta)
