"""What every hysteresis law is: its parameters, the Jenkins element, the first-harmonic rigidity and
Masing's rule (:class:`HysteresisLaw`)."""

from __future__ import annotations

import math
from dataclasses import KW_ONLY, dataclass
from typing import ClassVar

import numpy as np

from ...core.errors import InputError
from . import kernels


__all__ = ["LawParameter", "DELTA_EJ", "HysteresisLaw", "jenkins_rigidity", "masing_loop"]


@dataclass(frozen=True)
class LawParameter:
    """Name, SI unit, meaning and domain of one law parameter.

    The domain is the interval from ``low`` to ``high``, open at an end unless ``include_low`` or
    ``include_high`` closes it; the default ``(0, inf)`` is that of a scale. ``prior`` is the box a
    calibration samples it in, ``(dist, lower, upper)`` with ``dist`` ``"uniform"`` or ``"loguniform"``
    (``"of_ej_static"`` as a fourth item: the bounds are fractions of the damper's static rigidity);
    ``priors/cable.toml`` may override it.
    """

    name: str
    unit: str
    meaning: str
    _: KW_ONLY
    low: float = 0.0
    high: float = math.inf
    include_low: bool = False
    include_high: bool = False
    prior: tuple = ()

    def contains(self, v: np.ndarray) -> np.ndarray:
        """Boolean mask: the values ``v`` lie in the domain."""
        above = v >= self.low if self.include_low else v > self.low
        below = v <= self.high if self.include_high else v < self.high
        return above & below


# EJ_min + delta_EJ <= EJ_static: the stuck cable is at most the static rigidity (the thesis's Table 4.2)
DELTA_EJ = LawParameter("delta_EJ", "N m^2", "rigidity the slip part adds while the wires stick (EJ_max - EJ_min)",
                        prior=("loguniform", 0.02, 1.0, "of_ej_static"))


def jenkins_rigidity(x):
    """Describing function of a Jenkins element (unit spring in series with a slider), per unit stiffness.

    ``x = phi / chi_a`` is the element's slip curvature over the amplitude. Stuck (``x >= 1``): 1.
    Slipping (Caughey 1960), with ``theta = arccos(1 - 2 x)``::

        Re = (theta - sin(theta) cos(theta)) / pi,    Im = 4 x (1 - x) / pi = sin(theta)^2 / pi

    Parameters
    ----------
    x : array_like
        ``phi / chi_a`` >= 0.

    Returns
    -------
    ndarray of complex, shape of ``x``
    """
    x = np.asarray(x, dtype=float)
    xs = np.clip(x, 0.0, 1.0)
    theta = np.arccos(1.0 - 2.0 * xs)
    re = (theta - np.sin(theta) * np.cos(theta)) / np.pi
    return np.where(x >= 1.0, 1.0 + 0j, re + 1j * 4.0 * xs * (1.0 - xs) / np.pi)


@dataclass(frozen=True)
class HysteresisLaw:
    """Base of the strand-slip law families.

    Subclasses set :attr:`name` and :attr:`parameters` (each with its domain and prior box),
    :attr:`ordered` where parameters bound one another, :attr:`scale` and :attr:`typical` (what the
    virtual bench needs), and implement :meth:`_rigidity` (the describing function on validated,
    broadcast arrays) and :meth:`steady_loop`, and a :attr:`backbone` (a Masing law) or their own
    :meth:`_branch`, :meth:`_periodic` and :meth:`time_stepper`; then :func:`sbcal.model.laws.register`
    makes the law known to every command.
    """

    name: ClassVar[str] = ""
    parameters: ClassVar[tuple] = ()
    ordered: ClassVar[tuple] = ()
    """Pairs ``(lower, upper)`` of parameter names: the domain also needs ``lower < upper``."""
    min_tests: ClassVar[int] = 1
    """Tests (amplitudes) a cable state needs before the family is compared on it."""
    fitted: ClassVar[bool] = False
    """A family ``sbcal cable`` fits and compares (every parameter then needs a prior box)."""
    within: ClassVar[str] = ""
    """The fitted family that holds this law as a special case (``dahl`` in ``bouc_wen``): its alias."""
    summary: ClassVar[str] = ""
    """One line for ``sbcal cable --law``'s help."""
    scale: ClassVar[str] = ""
    """The parameter that sets the curvature where the wires slip [1/m] (the virtual bench's ``strand_slip`` value)."""
    typical: ClassVar[dict] = {}
    """Values of the shape parameters (all but ``delta_EJ`` and :attr:`scale`) the virtual bench takes
    when only the scale is given."""

    @property
    def parameter_names(self) -> tuple:
        """The law's parameter names, in order."""
        return tuple(p.name for p in self.parameters)

    def _arrays(self, params: dict) -> dict:
        names = self.parameter_names
        missing = [n for n in names if n not in params]
        unknown = sorted(set(params) - set(names))
        if missing or unknown:
            raise InputError(f"{self.name} law: expected parameters {', '.join(names)}"
                             + (f"; missing {missing[0]!r}" if missing else f"; unknown {unknown[0]!r}"))
        return {n: np.asarray(params[n], dtype=float) for n in names}

    def valid(self, **params) -> np.ndarray:
        """Boolean mask (broadcast shape of the parameters): the parameters lie in the law's domain
        (each finite and in its own, each pair of :attr:`ordered` increasing)."""
        p = self._arrays(params)
        ok = np.ones(np.broadcast_shapes(*(v.shape for v in p.values())), dtype=bool)
        for name, v in p.items():
            ok &= np.isfinite(v) & self._domain(name, v)
        with np.errstate(invalid="ignore"):
            for lower, upper in self.ordered:
                ok &= p[lower] < p[upper]
        return ok

    def _domain(self, name: str, v: np.ndarray) -> np.ndarray:
        return next(p for p in self.parameters if p.name == name).contains(v)

    def slip_rigidity(self, chi_a, **params) -> np.ndarray:
        """First-harmonic complex secant rigidity of the slip part at curvature amplitude ``chi_a``.

        Parameters
        ----------
        chi_a : array_like
            Curvature amplitude [1/m], >= 0.
        **params : float or array_like
            The law's parameters (:attr:`parameters`), broadcast against ``chi_a``.

        Returns
        -------
        ndarray of complex
            ``EJ_slip*`` [N m^2], broadcast shape; ``delta_EJ`` (real) at ``chi_a = 0``; NaN where
            the parameters are outside the law's domain.
        """
        p = self._arrays(params)
        chi = np.asarray(chi_a, dtype=float)
        ok = self.valid(**params)
        out = self._rigidity(np.maximum(chi, 0.0), **{k: np.where(ok, v, 1.0) for k, v in p.items()})
        return np.where(ok, out, np.nan)

    def seen_ratios(self, chi_ref: float, **params) -> dict:
        """Ratio parameters whose part in the bench's curves is over the law's slip wires above ``chi_ref`` only.

        A ratio ``r`` of two of the law's parts (as a point mass over a spread density) of which the bench, whose
        curvatures all exceed ``chi_ref`` [1/m], sees the second only above ``chi_ref``: the curves pin ``r / g``
        with ``g`` the share of that part above ``chi_ref``, not ``r``. The cable fit samples ``r / g``
        (:mod:`sbcal.inference.cable_coords`).

        Returns
        -------
        dict
            Ratio name -> ``ln g`` (broadcast shape of ``params``; ``-inf`` where none is above ``chi_ref``, NaN
            outside the law's domain); empty for a law without such a ratio (this base class).
        """
        return {}

    def energy_per_cycle(self, chi_a, **params) -> np.ndarray:
        """``W = pi Im(EJ_slip*) chi_a^2``: friction energy per cycle and unit length [J/m]."""
        return np.pi * self.slip_rigidity(chi_a, **params).imag * np.asarray(chi_a, dtype=float) ** 2

    def _rigidity(self, chi, **p):  # pragma: no cover - abstract
        raise NotImplementedError

    def loop_branch(self, chi, chi_a, **params):
        """Slip moment on the unloading branch of the steady loop between ``+-chi_a``, and its slopes.

        A rate-independent law's moment depends only on the curvature's path: under any periodic,
        odd curvature with one maximum ``chi_a`` per period (a sine with odd harmonics), it runs this
        branch while the curvature falls and ``-branch(-chi)`` while it rises, whatever the timing.
        The multi-harmonic solve (:mod:`sbcal.model.cable_harmonics`) evaluates the law so.

        Parameters
        ----------
        chi : array_like
            Curvature [1/m] in ``[-chi_a, chi_a]``.
        chi_a : array_like
            The loop's turning curvature [1/m], > 0.
        **params : float or array_like
            The law's parameters, broadcast against ``chi``.

        Returns
        -------
        m, dm_dchi, dm_dchi_a : ndarray
            Slip moment [N m], its slope along the branch [N m^2] and its change with the turning
            point at fixed ``chi`` [N m^2]; broadcast shape.
        """
        p = self._arrays(params)
        return self._branch(np.asarray(chi, dtype=float), np.asarray(chi_a, dtype=float), **p)

    def _branch(self, chi, chi_a, **p):
        """Masing's rule on the law's backbone (the laws that have one); other laws override."""
        backbone = getattr(self, "backbone", None)
        if backbone is None:  # pragma: no cover - every law of sbcal has one or overrides
            raise NotImplementedError(f"{self.name}: no steady-loop branch")
        return _masing_branch(lambda x: backbone(x, **p), chi, chi_a)

    def periodic_moment(self, chi, directions=None, **params):
        """Slip moment over one period of any periodic curvature, in its steady state.

        For curvatures with inner loops (several maxima per period), where :meth:`loop_branch` does
        not apply. ``chi`` holds samples over one period (last axis), monotone between neighbours: the
        samples must include the turning points. The moment at every sample depends on the whole path
        (its reversal points, the periodic state), so its derivatives come along the path (forward mode).

        Parameters
        ----------
        chi : ndarray, shape (n, n_t)
            Curvature samples [1/m] over one period.
        directions : ndarray, shape (n, n_t, k), optional
            Derivatives of the samples along ``k`` directions (e.g. a harmonic coefficient each).
        **params : ndarray, shape (n, 1)
            The law's parameters.

        Returns
        -------
        m : ndarray, shape (n, n_t)
            Slip moment [N m].
        dm : ndarray, shape (n, n_t, k)
            Its derivatives along ``directions`` (returned only with them).
        """
        p = self._arrays(params)
        chi = np.asarray(chi, dtype=float)
        dirs = np.zeros(chi.shape + (0,)) if directions is None else np.asarray(directions, dtype=float)
        m, dm = self._periodic(chi, dirs, **p)
        return m if directions is None else (m, dm)

    def _periodic(self, chi, dirs, **p):
        """Masing's rule with Madelung's memory on the backbone (the laws that have one)."""
        backbone = getattr(self, "backbone", None)
        if backbone is None:  # pragma: no cover - every law of sbcal has one or overrides
            raise NotImplementedError(f"{self.name}: no periodic evaluation")
        return _masing_periodic(lambda x: backbone(x, **p), chi, dirs)

    def time_stepper(self, params: dict, *, resolution: float = 1.0, linear=None):
        """The law's own hysteresis operator stepped in time, for the time-domain cable; None (the default):
        a Masing law, whose backbone gives it (a Jenkins population,
        :func:`sbcal.model.laws.steppers.law_stepper`, which validates ``params`` and calls this).

        Parameters
        ----------
        params : dict
            The law's parameters, each an ndarray of shape (n_sections,), inside the law's domain.
        resolution : float
            Cell density of a Jenkins population.
        linear : complex or ndarray of complex, optional
            The sections' ``EJ_min (1 + i beta)`` [N m^2] (Jenkins populations only).

        Returns
        -------
        A stepper (``start``, ``trial``, ``commit``; :mod:`sbcal.model.laws.steppers`) or None.
        """
        return None

    def steady_loop(self, chi_a: float, theta, **params) -> np.ndarray:  # pragma: no cover - abstract
        """Slip moment [N m] on the steady loop ``chi = chi_a cos(theta)``, theta in [0, 2 pi).

        The law's own hysteresis operator, not its describing function: the reference the tests
        hold :meth:`slip_rigidity` to. Scalar parameters.
        """
        raise NotImplementedError


def masing_loop(backbone, chi_a, theta):
    """Steady loop of a Masing law from its backbone (virgin curve) ``backbone(chi)``, chi >= 0.

    Unloading from ``chi_a`` (theta in [0, pi], chi falling): ``M = B(chi_a) - 2 B((chi_a - chi) / 2)``;
    loading (theta in (pi, 2 pi)): ``M = -B(chi_a) + 2 B((chi_a + chi) / 2)`` (Masing's doubling rule).
    Parallel Jenkins elements (Iwan models) obey it exactly.
    """
    theta = np.mod(np.asarray(theta, dtype=float), 2 * np.pi)
    chi = chi_a * np.cos(theta)
    top = backbone(np.asarray(chi_a, dtype=float))
    unloading = theta <= np.pi
    return np.where(unloading, top - 2 * backbone((chi_a - chi) / 2), -top + 2 * backbone((chi_a + chi) / 2))


_SLOPE_STEP = 1e-7  # relative step of the backbone's slope (Jacobians only: values are exact)


def _masing_branch(backbone, chi, chi_a):
    """:meth:`HysteresisLaw.loop_branch` of a Masing law: ``M = B(chi_a) - 2 B((chi_a - chi) / 2)``.

    The slopes use a forward difference of the backbone (they enter Newton's Jacobian only)."""
    u = np.maximum(0.5 * (chi_a - chi), 0.0)
    h = _SLOPE_STEP * (u + 1e-3 * chi_a) + 1e-300

    def slope(x, step):
        return (backbone(x + step) - backbone(x)) / step

    bu = slope(u, h)
    m = backbone(chi_a) - 2.0 * backbone(u)
    return m, bu, slope(chi_a, _SLOPE_STEP * chi_a + 1e-300) - bu


def _masing_periodic(backbone, chi, dirs):
    """:meth:`HysteresisLaw.periodic_moment` of a Masing law (parallel Jenkins elements obey it exactly).

    The steady state starts at the period's largest curvature on the outer loop it spans with the
    smallest. Reversal points are kept on a stack; each branch runs ``M = M_r + 2 B((chi - chi_r) / 2)``
    (odd ``B``) from the last reversal ``r``; once the curvature passes the reversal before it, the
    inner loop has closed and both points are dropped (Madelung's rule: the path rejoins the branch it
    left). Derivatives ride along: ``dM = dM_r + B'(u) (d chi - d chi_r)`` (``B'`` by a forward
    difference). The stack depends on the path only (compiled: :func:`sbcal.model.laws.kernels.masing_reversals`),
    so the backbone is evaluated once over all samples, then the recurrence runs compiled
    (:func:`sbcal.model.laws.kernels.masing_accumulate`). ``backbone`` takes and returns (n, any) arrays.
    """
    n, nt = chi.shape
    rows = np.arange(n)
    start = np.argmax(chi, axis=1)
    low = np.argmin(chi, axis=1)
    order = (start[:, None] + np.arange(nt + 1)[None, :]) % nt
    path = chi[rows[:, None], order]  # from the largest sample round to it again
    dpath = np.ascontiguousarray(dirs[rows[:, None], order], dtype=float)
    top, bottom = path[:, 0], chi[rows, low]
    h = (1e-7 * (top - bottom) + 1e-300)[:, None]
    ref = kernels.masing_reversals(np.ascontiguousarray(path, dtype=float))
    # each sample's distance from its reversal (column 0: the outer loop's half range)
    kr = np.where(ref >= 0, np.take_along_axis(path, np.maximum(ref, 0), axis=1), bottom[:, None])
    u = 0.5 * (path - kr)
    u[:, 0] = 0.5 * (top - bottom)
    x = np.abs(u)
    b = backbone(np.concatenate([x, x + h], axis=1))
    b0, b1 = b[:, :nt + 1], b[:, nt + 1:]
    slope = (b1 - b0) / h
    branch = 2.0 * (np.sign(u) * b0)
    # the outer loop of an odd periodic curvature: M(top) = B(half range)
    m_top = b0[:, 0]
    dm_top = slope[:, 0][:, None] * 0.5 * (dpath[:, 0] - dirs[rows, low])
    return kernels.masing_accumulate(ref, order, branch, slope, m_top, np.ascontiguousarray(dm_top),
                                         dpath, np.ascontiguousarray(dirs[rows, low], dtype=float))
