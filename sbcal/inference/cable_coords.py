"""The cable fit's sampled coordinates: the parameters the bench pins only in combination, sampled as that combination.

A law's slip part adds ``delta_EJ`` of rigidity while every wire sticks. Wires that slip below the least
curvature the bench reaches are slipped on every line, so the bench sees only the drop held by the others,
``delta_EJ * s`` with ``s`` the share of the slip rigidity still held at that curvature. The data pin the
product, not ``delta_EJ`` and the micro-slip onset apart: in ``ln delta_EJ`` and the onset the posterior is a
long curved ridge (the in-family zoned posterior's slowest direction, ``docs/cable.md``, "The engine on the
zoned posterior"). The engine samples ``u = ln delta_EJ + ln s`` instead (:class:`SeenShare`). ``s`` depends on
the law's other parameters only, so the map is triangular with a unit diagonal: its Jacobian is 1.

``s`` is the law's own first-harmonic secant rigidity at the reference curvature over ``delta_EJ``
(:meth:`sbcal.model.laws.base.HysteresisLaw.slip_rigidity`, real part), for any law; the reference is the
least, over the fit's lines, of the largest curvature along the arm at the fit's start. (The slope of a Masing
law's virgin curve there, the share of its wires still stuck, mixed no better: in-family zoned posterior, tau max
182 either way, ``docs/cable.md``.)

The same holds for a ratio of two of the law's parts of which the bench sees one only above the reference
(:meth:`~sbcal.model.laws.base.HysteresisLaw.seen_ratios`: ``iwan5``'s point mass over its spread density): the
engine samples the ratio over the share ``g`` it sees, ``r / g`` (:class:`SeenRatio`, Jacobian ``g``, carried by
the prior's density). Its ridge with the onset was the zoned posterior's slowest pair after the first shear; with
both, the in-family zoned posterior converges in 9 600 steps, tau 91 (``docs/cable.md``). The stored draws are
natural values (:class:`sbcal.inference.priors.Shear`).

Left after both shears, on a posterior the zoned law fits but does not hold (the ``zoned_iwan5`` row of the cross-law
matrix): the micro-slip onset, a narrow core far below the reference and a flat shoulder up to it at the same
log-density, which differential evolution crosses in hundreds of steps (tau 563). A curvature scale of the law that
can lie below the reference is such a parameter: the engine redraws it from its whole box every few steps, the others
held (:attr:`sbcal.inference.priors.Prior.redrawn`, :func:`unseen_onsets`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ..model.laws import law_for
from ..model.laws.zones import ZonedLaw
from .likelihood import JointLikelihood
from .priors import Shear

__all__ = ["SeenRatio", "SeenShare", "reference_curvature", "seen_share_target", "unseen_onsets"]

SHARE_FLOOR = -12.0
"""ln of the least share the coordinate follows: below it (a law whose wires all slip below the bench's
curvatures, which the bench cannot tell from a stiffer cable) the shear stops growing."""

RATIO_CEILING = math.log(4.0)
"""ln of the most a ratio is scaled by (:class:`SeenRatio`: its share seen at least a quarter); beyond, the ratio
is sampled as if a quarter were seen (a ridge the bench cannot straighten further: most of the part slipped)."""


@lru_cache(maxsize=None)
def _middle_law(law: str):
    lw = law_for(law)
    return lw.base if isinstance(lw, ZonedLaw) else lw


@dataclass(frozen=True)
class SeenShare:
    """``ln s``: the share of a law's slip rigidity still held at the curvature ``chi_ref`` [1/m] (picklable).

    ``SeenShare(law, chi_ref)(params) -> (n,)`` for natural values by name (every parameter of the law's
    middle but ``delta_EJ``), at least :data:`SHARE_FLOOR`, NaN outside the law's domain. For a zoned law, its
    middle's.
    """

    law: str
    chi_ref: float

    def __call__(self, params: dict) -> np.ndarray:
        lw = _middle_law(self.law)
        shape = {k: np.atleast_1d(np.asarray(params[k], float)) for k in lw.parameter_names if k != "delta_EJ"}
        n = max(v.size for v in shape.values())
        with np.errstate(divide="ignore", invalid="ignore"):
            s = lw.slip_rigidity(self.chi_ref, delta_EJ=np.ones(n), **shape).real  # NaN outside the domain
            # nothing held (every wire slipped far below chi_ref) is a point of the law: at the floor, not outside
            return np.log(np.maximum(s, np.exp(SHARE_FLOOR)))


@dataclass(frozen=True)
class SeenRatio:
    """``-ln g``: a ratio parameter ``name`` of a law sampled as ``r / g``, ``g`` its share seen above ``chi_ref``
    [1/m] (:meth:`~sbcal.model.laws.base.HysteresisLaw.seen_ratios`; picklable).

    ``SeenRatio(law, chi_ref, name)(params) -> (n,)`` for natural values by name (every parameter of the law's
    middle but ``name`` and ``delta_EJ``), NaN outside the law's domain. For a zoned law, its middle's.
    """

    law: str
    chi_ref: float
    name: str

    def __call__(self, params: dict) -> np.ndarray:
        lw = _middle_law(self.law)
        shape = {k: np.atleast_1d(np.asarray(params[k], float)) for k in lw.parameter_names
                 if k not in ("delta_EJ", self.name)}
        n = max(v.size for v in shape.values())
        return -lw.seen_ratios(self.chi_ref, delta_EJ=np.ones(n), **{self.name: np.zeros(n)}, **shape)[self.name]


def reference_curvature(like: JointLikelihood, params: dict) -> float:
    """The least, over the lines, of the largest curvature amplitude along the arm [1/m] at one parameter set
    (natural values by name): the curvature below which every wire is slipped on every line."""
    one = {n: np.atleast_1d(np.asarray(params[n], float))[:1] for n in like.prior.model_names}
    st, _ = like.model.state(like.damper, like.freq_hz, **one)
    top = st.curvature_range[..., 1]
    top = top[np.isfinite(top) & (top > 0)]
    if not top.size:
        raise ValueError("no line of the start reached a finite curvature")
    return float(top.min())


def unseen_onsets(law: str, chi_ref: float, start: dict, prior) -> tuple:
    """The curvature scales (unit 1/m, log-uniform in ``prior``) of ``law``'s middle that may lie below ``chi_ref``
    [1/m], below every curvature of the bench, where the data see them only through the shares above and the
    posterior is the prior's over most of their box: the law's onsets (every curvature scale but its :attr:`scale`,
    where the wires slip) whose box reaches below ``chi_ref``, and any that ``start`` (natural values by name) puts
    there. Not the start alone: on the cross-law matrix's zoned row the uniform fit's median put ``chi_micro`` above
    the reference and the zoned posterior spread far below it (tau 593 without the redraw)."""
    lw = _middle_law(law)
    out = []
    for p in lw.parameters:
        if p.unit != "1/m" or p.name not in prior.names or not prior.box(p.name)[0]:
            continue
        if (p.name != lw.scale and prior.box(p.name)[1] < chi_ref) or start[p.name] < chi_ref:
            out.append(p.name)
    return tuple(out)


def seen_share_target(like: JointLikelihood, start: dict) -> JointLikelihood:
    """``like`` in the sheared coordinates: the law's seen ratios (:class:`SeenRatio`) first, then
    ``u = ln delta_EJ + ln s`` (:class:`SeenShare`, which reads them), the reference curvature at ``start`` (natural
    values by name), and its :func:`unseen_onsets` on a log scale redrawn; ``like`` itself where its law has no
    ``delta_EJ`` on a log scale."""
    prior = like.prior
    law = getattr(like.model, "law", None)
    if law is None or "delta_EJ" not in prior.names or not prior.box("delta_EJ")[0]:
        return like
    chi = reference_curvature(like, start)
    middle = _middle_law(law)
    onsets = unseen_onsets(law, chi, start, prior)
    seen = middle.seen_ratios(chi, **{k: start[k] for k in middle.parameter_names})
    ratios = [Shear(name=n, offset=SeenRatio(law, chi, n), lower=0.0, upper=RATIO_CEILING, kind="scale")
              for n in seen if n in prior.names and not prior.box(n)[0] and prior.box(n)[1] >= 0]
    share = Shear(name="delta_EJ", offset=SeenShare(law, chi), lower=SHARE_FLOOR)
    return JointLikelihood(like.likes, prior.sheared(*ratios, share).redrawing(*onsets), like.model)
