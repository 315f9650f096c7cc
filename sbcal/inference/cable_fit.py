"""The cable law of a damper: one hysteresis law per cable state, fitted jointly over all its tests.

A *cable state* is what a test label's suffix says (``1-1-oiled`` is the oiled cable; tests without
a suffix are the ``dry`` cable). All tests of one state share one cable — ``EJ_min``,
``beta_material`` and the law's parameters (:mod:`sbcal.model.laws`) — and all tests of one damper
share its geometry (the mass offsets ``a1``, ``a2``). The forward model is the distributed cable of
:class:`sbcal.model.cable.CableModel` on the concatenated lines of the state's tests (each test's commanded
amplitude per line; a sweep restarts at each test), the likelihood the noise-only multivariate t of
every test's runs (:class:`sbcal.inference.likelihood.TestLikelihood`, no discrepancy: the law must explain the
runs within the bench's scatter), the posterior the engine's (:func:`sbcal.inference.sampler.sample`). Families
are compared by PSIS-LOO grouped by run (:mod:`sbcal.inference.cable_compare`).

Measurement-chain effects can ride on top (``effects``: ``sensor_delay``, ``fixture_mass``,
``base_rocking``, with the boxes of ``priors/extensions.toml``), one value per cable state: the
diagnosis's secondary effects.

Stored as ``<runs>/<damper>/cable-<state>/posterior.nc`` + ``summary.json`` (:func:`store_cable`).
"""

from __future__ import annotations

import json
import warnings
from functools import cached_property
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..core.seeds import job_seed, seed_key
from ..data.labels import cable_state, state_tests
from ..model.cable import DEFAULT_SECTIONS, CableModel
from ..model.cable_harmonics import DEFAULT_HARMONICS, HarmonicBalance
from ..model.damper import Damper
from ..model.laws import fitted_laws, law_for
from ..model.laws.zones import ZONE_PARAMETERS, ZONED_SUFFIX, ZonedLaw
from .cable_start import cable_start, fit_streams, polish_mode, screen, screen_families, unscreened
from .cable_compare import compare_families, zoned_candidate
from .cable_coords import seen_share_target
from .calibrate import likelihood_for
from .checks import ALPHA, GLOBAL_ALPHA, curve_moments, discrepancy, materiality, predictive_check, qualifier
from .distortion import predicted_distortion
from .likelihood import JointLikelihood
from .priors import Prior, cable_prior, extension_prior
from .sampler import SamplerConfig, sample
from .stats import loo


__all__ = ["SECONDARY", "compared_laws", "CableForward", "CableFit", "cable_likelihood", "cable_start",
           "cable_seed", "polish_mode", "sample_cable", "fit_cable", "fit_damper_cable", "stored_correction", "zoned_start", "law_curves", "store_cable", "read_cable", "cable_config"]

SECONDARY = {"sensor_delay": ("delay_s",), "fixture_mass": ("fixture_mass_kg",), "base_rocking": ("rocking_rad_per_m",)}
"""Effects that compose with the cable model (on the measured signal, or the clamp's rocking), by
their parameters."""

def compared_laws(laws, tests) -> tuple:
    """The families of ``laws`` a comparison over ``tests`` uses: those with their ``min_tests`` in every
    cable state (a family is compared on all of a damper's states or on none)."""
    fewest = min(len(m) for m in state_tests(tests).values())
    return tuple(law for law in laws if law_for(law).min_tests <= fewest)


def cable_config(ndim: int, *, workers: int = 2, max_steps: int | None = None, max_draws: int = 250) -> SamplerConfig:
    """The engine's settings for a cable fit (the policy is the engine's; a cap that keeps a stuck
    fit within minutes: the cable model costs ~1 ms per parameter set). The cap, unless given, is
    ``max(8000, 1200 ndim)`` steps: differential evolution's autocorrelation time grows with the dimension (tau
    5-10 ``ndim`` steps measured on the cable posteriors) and the rule keeps 50 of them in the second half of the
    run, so a 17-parameter zoned law needs 100 tau, 9 600 steps in-family and ~17 000 on the cross-law matrix's
    misspecified zoned row (tau 172 with the redraw, ``docs/cable.md``), where a uniform law's 6-10 parameters
    converge in 1 000-6 000. The independence proposal bends
    along up to six of the posterior's widest directions (a one-test state's law is a thin curved ridge),
    and the first half of every chain is burn-in: the early rounds' proposals, fitted before the chain
    reached the ridge's tails, read them short when a fifth is discarded (``docs/calibration.md``). Where a
    quadratic of the log-density predicts the kept steps, proposals are screened by it before the model is
    called (:mod:`sbcal.inference.surrogate`; a multi-test state's law: half the calls)."""
    return SamplerConfig(nwalkers=2 * ndim + 2, max_steps=max_steps or max(8000, 1200 * ndim), max_draws=max_draws,
                         first_steps=300,
                         de_population=4 * ndim + 8, de_generations=60, workers=workers, bend=6,
                         burn_fraction=0.5, screen=True)


@dataclass(frozen=True)
class CableForward:
    """The forward model of a cable state's joint likelihood (picklable).

    ``CableForward(...)(damper, freq_hz, **params) -> complex (n, n_lines)`` on the concatenated lines.

    Attributes
    ----------
    law : str
        A family of :data:`sbcal.model.laws.LAWS`.
    amplitude_mm_pp : ndarray, shape (n_lines,)
        Commanded amplitude per line [mm p-p].
    segments : ndarray of int, shape (n_lines,)
        Test index per line.
    effects : tuple of str
        Secondary effects of :data:`SECONDARY` applied on top.
    sections : int
        Gauss sections per arm of the cable model.
    correction : ndarray of complex, shape (n_lines,), optional
        The multi-harmonic solve over the first-harmonic model per line, ``f_uu / f_uu_first``, multiplying
        the cable's ``f_uu`` (1 where the first harmonic suffices; :mod:`sbcal.inference.harmonic_refit`).
    start : ndarray of complex, shape (2, 2 n_lines), optional
        Where the cable model's Newton starts every line (:meth:`sbcal.model.cable.CableModel.loads` of one
        parameter set near the posterior: :meth:`near`); default the fully slipped cable.
    """

    law: str
    amplitude_mm_pp: np.ndarray
    segments: np.ndarray
    effects: tuple = ()
    sections: int = DEFAULT_SECTIONS
    correction: np.ndarray | None = field(default=None, compare=False)
    start: np.ndarray | None = field(default=None, compare=False)
    model: CableModel = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        object.__setattr__(self, "model", CableModel(law_for(self.law), sections=self.sections))

    def _split(self, params):
        chain = {k: params[k] for k in ("delay_s", "fixture_mass_kg") if k in params}
        return {k: v for k, v in params.items() if k not in chain}, chain

    def _measured(self, freq_hz, fuu, chain):
        omega = 2 * np.pi * np.asarray(freq_hz, float)
        if "fixture_mass_kg" in chain:
            fuu = fuu - omega**2 * np.asarray(chain["fixture_mass_kg"], float).reshape(-1, 1)
        if "delay_s" in chain:
            fuu = fuu * np.exp(-1j * omega * np.asarray(chain["delay_s"], float).reshape(-1, 1))
        return fuu

    def _corrected(self, fuu):
        return fuu if self.correction is None else fuu * self.correction

    def __call__(self, damper: Damper, freq_hz, **params):
        cable, chain = self._split(params)
        fuu = self.model.dynamic_stiffness(damper, freq_hz, self.amplitude_mm_pp, segments=self.segments,
                                           start=self.start, **cable)
        return self._measured(freq_hz, self._corrected(fuu), chain)

    def near(self, damper: Damper, freq_hz, params: dict) -> "CableForward":
        """This model with every line's Newton started from the cable's state at ``params`` (natural values
        by name, one set): the same answers to the solve's tolerance, fewer evaluations for sets near it (a
        fit's posterior near its start). Itself where that state is not finite."""
        cable, _ = self._split({k: np.atleast_1d(np.asarray(v, float))[:1] for k, v in params.items()})
        loads = self.model.loads(damper, freq_hz, self.amplitude_mm_pp, segments=self.segments, **cable)
        return replace(self, start=loads) if np.all(np.isfinite(loads)) else self

    def state(self, damper: Damper, freq_hz, *, continuation: bool = True, **params):
        """The cable's steady state (sections, curvature range, folds; first harmonic) and the measured ``f``
        (with the :attr:`correction`)."""
        cable, chain = self._split(params)
        st = self.model.state(damper, freq_hz, self.amplitude_mm_pp, segments=self.segments,
                              continuation=continuation, **cable)
        return st, self._measured(freq_hz, self._corrected(st.f_uu), chain)

    def harmonic_state(self, damper: Damper, freq_hz, *, harmonics: int, **params):
        """The same cable solved with ``harmonics`` odd harmonics (:class:`sbcal.model.cable_harmonics.HarmonicBalance`).

        Returns
        -------
        state : HarmonicState
            The cable's multi-harmonic steady state, shapes ``(n, n_lines)``.
        f_uu, first : ndarray of complex, shape (n, n_lines)
            Its ``f_uu`` and the first-harmonic model's [N/m], both measured as ``f`` is (with the chain's effects).
        """
        cable, chain = self._split(params)
        st = HarmonicBalance(self.model, harmonics=harmonics).state(damper, freq_hz, self.amplitude_mm_pp, **cable)
        return st, self._measured(freq_hz, st.f_uu, chain), self._measured(freq_hz, st.first_harmonic, chain)

    def harmonic_correction(self, damper: Damper, freq_hz, *, harmonics: int = DEFAULT_HARMONICS, **params):
        """The multi-harmonic solve over the first-harmonic model per line at one parameter set (each value of
        ``params`` of size 1): ``(c, solved)``, ``c = f_uu / f_uu_first`` of the cable (complex, ``(n_lines,)``;
        1 where the solve did not converge) and ``solved`` (bool, ``(n_lines,)``)."""
        st, _, _ = self.harmonic_state(damper, freq_hz, harmonics=harmonics, **params)
        with np.errstate(invalid="ignore", divide="ignore"):
            ratio = st.f_uu[0] / st.first_harmonic[0]
        solved = st.converged[0] & np.isfinite(ratio)
        return np.where(solved, ratio, 1.0 + 0j), solved


def _prior(law: str, damper: Damper, effects, prior_path=None) -> Prior:
    """The cable family's boxes plus those of the secondary effects (one value per cable state)."""
    base = cable_prior(law, damper, base_path=prior_path)
    boxes = {n: base.box(n) for n in base.names}
    for e in effects:
        if e not in SECONDARY:
            raise InputError(f"effect {e!r} does not compose with the cable model; known: {', '.join(SECONDARY)}")
        ext = extension_prior(e, damper, base_path=prior_path)
        for n in SECONDARY[e]:
            boxes[n] = ext.box(n)
    name = law + "".join(f"+{e}" for e in effects)
    return Prior.from_boxes(name, boxes)


def cable_likelihood(damper: Damper, data, tests, law: str, *, effects=(), prior_path=None) -> JointLikelihood:
    """The joint noise-only likelihood of one cable state's tests (their kept runs in ``data``, a
    :class:`sbcal.data.clean_bench.CleanBench`) under a law family."""
    tests = list(tests)
    states = {cable_state(t) for t in tests}
    if len(states) != 1:
        raise InputError(f"a cable fit takes the tests of one cable state, got {', '.join(sorted(states))}")
    prior = _prior(law, damper, tuple(effects), prior_path)
    likes = []
    for t in tests:
        likes.append(likelihood_for(damper, data.kept(damper.name, t), prior))
    amp = np.concatenate([lk.amplitude_mm_pp for lk in likes])
    seg = np.concatenate([np.full(lk.freq_hz.size, i) for i, lk in enumerate(likes)])
    return JointLikelihood(likes, prior, CableForward(law, amp, seg, tuple(effects)))


@dataclass(frozen=True)
class CableFit:
    """One cable state's posterior under one law family.

    Attributes
    ----------
    damper, state, law : str
    tests : tuple of str
    effects : tuple of str
    result : SampleResult
    like : JointLikelihood
    loo : sbcal.inference.stats.Loo
        PSIS-LOO grouped by run (runs of all tests, in test order).
    refit : dict, optional
        The harmonic refit's record where one was made (:func:`sbcal.inference.harmonic_refit.refit_harmonics`):
        JSON-ready, stored as ``harmonic_refit`` in the summary.
    distortion : dict, optional
        :attr:`harmonics` where it was already made for this posterior (by the harmonic refit's job, in
        another process): then it is not solved again.
    """

    damper: str
    state: str
    law: str
    tests: tuple
    effects: tuple
    result: object
    like: object
    loo: object
    refit: dict | None = None
    distortion: dict | None = field(default=None, repr=False, compare=False)

    def median(self) -> dict:
        return {n: float(np.median(v)) for n, v in self.result.draws.items()}

    @cached_property
    def curves(self) -> tuple[list, list]:
        """Posterior mean and variance of the model curves per test (:func:`sbcal.inference.checks.curve_moments`
        of every draw), made once: ``sbcal cable`` judges the best family with them and stores them."""
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            moments = [curve_moments(mu) for mu in self.like.predict(self.result.flat())]
        return [m[0] for m in moments], [m[1] for m in moments]

    @cached_property
    def harmonics(self) -> dict:
        """The base force's distortion the posterior median predicts per line, and how far the first-harmonic
        model is from the multi-harmonic solve (:func:`sbcal.inference.distortion.predicted_distortion`), made
        once (or given as ``distortion``): :func:`store_cable` stores it and ``sbcal cable`` prints its largest."""
        if self.distortion is not None:
            return self.distortion
        return predicted_distortion(self.like, self.median(), self.tests)


def cable_seed(seed, damper: str, state: str, law: str, effects=()) -> np.random.SeedSequence:
    """The stream of one cable fit, keyed by what it is (:func:`sbcal.core.seeds.job_seed`): ``sbcal cable``,
    ``sbcal diagnose`` and ``sbcal run`` draw the same numbers for the same seed and data."""
    return job_seed(seed, "cable", damper, state, law, *effects)


def sample_cable(like: JointLikelihood, *, seed: np.random.SeedSequence, config: SamplerConfig | None = None,
                 start=None, progress: str | None = None):
    """The cable-law fit, the one every command uses: :func:`cable_start`, then the engine, in the coordinates
    of :mod:`sbcal.inference.cable_coords` (``delta_EJ`` sheared by the share of the law's drop the bench sees,
    the reference curvature at the start; the draws are stored in ``delta_EJ``), the cable model solving every
    line from its state at the start (:meth:`CableForward.near`).

    Parameters
    ----------
    like : JointLikelihood
        A cable state's likelihood (:func:`cable_likelihood`).
    seed : numpy.random.SeedSequence
        The fit's stream (:func:`cable_seed`); the start and the engine each get a child of it.
    config : SamplerConfig, optional
        Default :func:`cable_config`.
    start : dict or ndarray, optional
        Natural values by name to polish the mode from (a parameter it does not name starts at the middle
        of its box, in its own scale), or a start in the coordinates of ``like.prior`` ``(ndim,)`` made with
        this fit's own start stream (:func:`sbcal.inference.cable_start.screen`); default :func:`cable_start`.
    progress : str, optional

    Returns
    -------
    SampleResult
    """
    s_start, s_sample = fit_streams(seed)
    prior = like.prior
    if start is None:
        start = cable_start(like, np.random.default_rng(s_start))
    if isinstance(start, dict):
        start = {n: float(start.get(n, m)) for n, m in prior.middle().items()}
    else:
        start = dict(zip(prior.names, prior.to_natural(np.asarray(start, float)[None])[0]))
    target = seen_share_target(_near(like, start), start)
    return sample(target, seed=s_sample, config=config or cable_config(prior.ndim), start=start, progress=progress)


def _near(like: JointLikelihood, start: dict) -> JointLikelihood:
    """``like`` whose cable model starts every line's Newton from the cable's state at ``start`` (natural values
    by name; :meth:`CableForward.near`): the posterior's sets lie near it (0.45-0.66x of a model call, ``docs/cable.md``, "Newton")."""
    fw = like.model
    near = fw.near(like.damper, like.freq_hz, like.model_params(start)) if isinstance(fw, CableForward) else fw
    return like if near is fw else JointLikelihood(like.likes, like.prior, near)


def fit_cable(damper: Damper, data, tests, law: str, *, seed: int, effects=(), workers: int = 2,
              max_steps: int | None = None, max_draws: int = 250, start=None, prior_path=None,
              progress: str | None = None) -> CableFit:
    """Sample one cable state's law (see the module docstring).

    Parameters
    ----------
    damper : Damper
    data : CleanBench
        The recordings with their stored cleaning (:class:`sbcal.data.clean_bench.CleanBench`).
    tests : sequence of str
        The tests of one cable state.
    law : str
        A fitted family (:func:`sbcal.model.laws.fitted_laws`).
    seed : int
        The user's seed; the fit's stream is :func:`cable_seed` of it.
    effects : sequence of str
        Secondary effects on top (:data:`SECONDARY`).
    workers, max_steps, max_draws : int
        As :func:`cable_config` (the draws do not depend on ``workers``; ``max_steps`` None: its cap).
    start : dict or ndarray, optional
        Natural values by name to polish the mode from, or a start in sampled coordinates
        (``(ndim,)``, e.g. the family screen's); default :func:`cable_start`.
    prior_path : path-like, optional
        The prior file of the base geometry boxes (``--priors``).
    progress : str, optional
    """
    tests = tuple(tests)
    like = cable_likelihood(damper, data, tests, law, effects=effects, prior_path=prior_path)
    state = cable_state(tests[0])
    config = cable_config(like.prior.ndim, workers=workers, max_steps=max_steps, max_draws=max_draws)
    res = sample_cable(like, seed=cable_seed(seed, damper.name, state, law, tuple(effects)), config=config,
                       start=start, progress=progress)
    return CableFit(damper=damper.name, state=state, law=law, tests=tests, effects=tuple(effects), result=res,
                    like=like, loo=loo(res.log_likelihood))


def law_curves(law: str, draws: dict, chi, zone: str = "middle") -> tuple[np.ndarray, np.ndarray]:
    """The cable law's equivalent rigidity ``Re EJ*`` [N m^2] and loss factor ``Im EJ* / Re EJ*`` at
    curvature amplitudes ``chi`` [1/m], per posterior draw: two arrays (n_draws, len(chi)). A zoned
    law's (:mod:`sbcal.model.laws.zones`) in its ``zone`` (``middle``, ``clamp`` or ``mass``)."""
    model = law_for(law)
    chi = np.asarray(chi, float)[None, :]
    col = {k: np.asarray(v, float).reshape(-1, 1) for k, v in draws.items()}
    lp, ratio = {k: col[k] for k in model.parameter_names}, 1.0
    if isinstance(model, ZonedLaw):
        _, _, lp, ratio = next(z for z in model.zones(lp) if z[0] == zone)
        model = model.base
    ej = col["EJ_min"] * ratio * (1 + 1j * col["beta_material"]) + model.slip_rigidity(chi, **lp)
    return ej.real, ej.imag / ej.real


def _curvature_ranges(fit: CableFit) -> dict:
    """Per test, the range of arm curvature amplitudes [1/m] the posterior median's steady state
    reached over its lines, and the lines with two steady states (folds)."""
    like = fit.like
    med = {k: np.array([v]) for k, v in fit.median().items()}
    st, _ = like.model.state(like.damper, like.freq_hz, continuation=True, **med)
    out, start = {}, 0
    for t, lk in zip(fit.tests, like.likes):
        n = lk.freq_hz.size
        cr = st.curvature_range[0, start:start + n]  # (lines, 2): least and largest over both arms
        out[t] = {"curvature_min": float(cr[:, 0].min()), "curvature_max": float(cr[:, 1].max()),
                  "fold_hz": [float(f) for f in lk.freq_hz[st.fold[0, start:start + n]]],
                  "not_converged_hz": [float(f) for f in lk.freq_hz[~st.converged[0, start:start + n]]]}
        start += n
    return out


def _remainder(fit: CableFit, curves=None) -> tuple[dict, dict]:
    """What the fit leaves, judged as the diagnosis judges a verdict's model (:mod:`sbcal.inference.checks`):
    ``(remainder, discrepancy)``. ``remainder``: the ``qualifier`` (``complete``/``partial``), rms z, lines
    off and the global check of the run means about the posterior curves (every draw); ``discrepancy``:
    per calibrated amplitude the spread beyond the noise (zero when ``complete``), which ``sbcal predict``
    adds to its bands (:func:`sbcal.design.predict.model_error_of`)."""
    like = fit.like
    mean, var = fit.curves if curves is None else curves
    check = predictive_check(like.likes, mean, var, ALPHA, like.prior.ndim)
    word = qualifier(check, GLOBAL_ALPHA)
    remainder = {"qualifier": word, "rms_z": check.rms_z, "lines_off": check.lines_off, "n_lines": check.n_lines,
                 "global": check.global_, "alpha": ALPHA, "global_alpha": GLOBAL_ALPHA}
    disc = discrepancy(like.likes, mean, var, partial=word == "partial")
    if word == "partial":  # is it material? (docs/diagnose.md, "Complete within")
        remainder["materiality"] = materiality(disc, like.likes)
    return remainder, disc


def store_cable(fit: CableFit, directory, *, meta: dict, comparison: dict | None = None, curves=None) -> dict:
    """Write ``posterior.nc`` + ``summary.json`` of a cable fit into ``directory``; returns the summary.

    The netCDF holds the posterior, the log-probability, the pointwise log-likelihood by run
    (``runs``, dim ``obs`` with ``obs_test``/``obs_run`` coordinates), the lines (frequency, amplitude,
    test) and the run means observed. The summary adds the law, the tests, each test's curvature range
    and folds, what the fit leaves (``remainder``, ``discrepancy``: :func:`_remainder`), the base force's
    predicted distortion per line (``harmonics``: :attr:`CableFit.harmonics`), the convergence and
    (with ``comparison``) the family comparison. ``curves``: the posterior mean and variance of the model
    curves per test (``([mean], [var])``, :func:`sbcal.inference.checks.curve_moments` of every draw) when
    the caller has them, else computed here.
    """
    from ..core._io import write_json
    from .runs import parameter_summary, versions, write_inference_data

    res, like = fit.result, fit.like
    obs_test = np.concatenate([np.full(lk.y.shape[1], t) for t, lk in zip(fit.tests, like.likes)])
    freq = like.freq_hz
    line_test = np.concatenate([np.full(lk.freq_hz.size, t) for t, lk in zip(fit.tests, like.likes)])
    ybar = np.concatenate([lk.ybar for lk in like.likes], axis=1)
    summary = {
        "damper": fit.damper, "state": fit.state, "law": fit.law, "effects": list(fit.effects),
        "tests": list(fit.tests), "parameters": parameter_summary(res), **res.convergence_dict(),
        "acceptance": float(np.mean(res.acceptance)), "wall_s": res.wall_s, "n_draws": int(res.log_prob.size),
        "elpd_loo": fit.loo.elpd, "elpd_se": fit.loo.se, "tests_reached": _curvature_ranges(fit),
        **dict(zip(("remainder", "discrepancy"), _remainder(fit, curves))),
        "harmonics": fit.harmonics, "harmonic_refit": fit.refit,
        "prior": like.prior.as_dict(), "comparison": comparison, "versions": versions(),
        "seed_key": seed_key("cable", fit.damper, fit.state, fit.law, *fit.effects), **meta,
    }
    groups = {
        "posterior": dict(res.draws), "sample_stats": {"lp": res.log_prob}, "log_likelihood": {"runs": res.log_likelihood},
        "constant_data": {"freq_hz": freq, "amplitude_mm_pp": like.model.amplitude_mm_pp, "line_test": line_test,
                          "obs_test": obs_test},
        "observed_data": {"logmag_mean": ybar[0], "phase_mean": ybar[1]},
        "dims": {"runs": ["obs"], "freq_hz": ["line"], "amplitude_mm_pp": ["line"], "line_test": ["line"],
                 "obs_test": ["obs"], "logmag_mean": ["line"], "phase_mean": ["line"]},
    }
    c = like.model.correction
    if c is not None:  # a used harmonic refit's correction, per line: what its draws were fitted with
        groups["constant_data"].update(correction_re=np.asarray(c).real, correction_im=np.asarray(c).imag)
        groups["dims"].update(correction_re=["line"], correction_im=["line"])
    d = Path(directory)
    write_inference_data(d / "posterior.nc", groups, attrs={"summary": json.dumps(summary, sort_keys=True)})
    write_json(d / "summary.json", summary, indent=1)
    return summary


def read_cable(directory) -> tuple[dict, dict]:
    """``(summary, draws)`` of a stored cable fit (``draws``: name -> flattened posterior draws)."""
    from .runs import read_summary
    from .stats import read_netcdf

    if (Path(directory) / "summary.json").is_file() and not (Path(directory) / "posterior.nc").is_file():
        raise InputError(f"{directory}: posterior.nc is missing")
    s = read_summary(directory)
    if s is None or "law" not in s:
        raise InputError(f"{directory}: no cable-law run here (summary.json missing or not a cable fit; "
                         "'sbcal cable' or 'sbcal run' writes one)")
    try:
        post = read_netcdf(Path(directory) / "posterior.nc").posterior
    except (OSError, ValueError, KeyError) as e:
        raise InputError(f"{directory}: cannot read the cable posterior ({e})") from None
    return s, {n: np.asarray(post[n]).ravel() for n in post.data_vars}


def stored_correction(directory) -> np.ndarray | None:
    """The harmonic refit's per-line correction a stored cable fit was fitted with (complex, ``(n_lines,)``, its
    lines in the order of the stored ``freq_hz``; :mod:`sbcal.inference.harmonic_refit`), or None: the fit is the
    first-harmonic model's."""
    from .stats import read_netcdf

    try:
        const = read_netcdf(Path(directory) / "posterior.nc").constant_data
    except (OSError, ValueError, KeyError, AttributeError) as e:
        raise InputError(f"{directory}: cannot read the cable posterior ({e})") from None
    if "correction_re" not in const:
        return None
    return np.asarray(const["correction_re"]) + 1j * np.asarray(const["correction_im"])


def zoned_start(uniform: dict, prior: Prior) -> dict:
    """Where a zoned fit starts: the uniform law's values (``uniform``: natural values by name, e.g. its
    posterior median; those of ``prior``, the uniform fit's, are kept) with every zone ratio 1 — the same
    cable, the zoned law's nested uniform member; the zones' lengths are left to :func:`sample_cable`
    (the middle of their box). The engine polishes the mode from there: a local ascent from the uniform
    fit's mode, instead of a global search in twice the dimensions."""
    out = {k: float(v) for k, v in uniform.items() if k in prior.names}
    out.update({p.name: 1.0 for p in ZONE_PARAMETERS if p.name.endswith("_ratio")})
    return out


def fit_damper_cable(damper: Damper, data, tests=None, *, laws=None, seed=0, prior_path=None,
                     workers: int = 2, progress: bool = True) -> tuple[dict, dict]:
    """Every cable state of a damper under every family (default: :func:`compared_laws` of
    :func:`~sbcal.model.laws.fitted_laws`, then the best one's zoned law where :func:`zoned_candidate` says so);
    ``(fits, comparison)`` with ``fits[law][state]`` and the comparison of :func:`compare_families`.
    With several families, each one's start is made first and a family far below the best there is not
    sampled (:func:`sbcal.inference.cable_start.screen`; named in the comparison's ``screened``).
    The harmonic refit comes after (:func:`sbcal.inference.harmonic_refit.refit_harmonics`)."""
    tests = list(data.tests(damper.name) if tests is None else tests)
    groups = state_tests(tests)
    default = laws is None
    laws = compared_laws(fitted_laws(), tests) if default else tuple(laws)
    fits, modes, screened = {}, {}, {}

    def fit_law(law, starts=None):
        fits[law] = {}
        for state, members in sorted(groups.items()):
            label = f"{damper.name} cable {state} ({law})" if progress else None
            fits[law][state] = fit_cable(damper, data, members, law, seed=seed, prior_path=prior_path, progress=label,
                                         workers=workers, start=(starts or {}).get(state))

    if len(laws) > 1:
        jobs = {law: {state: (cable_likelihood(damper, data, members, law, prior_path=prior_path),
                              cable_seed(seed, damper.name, state, law))
                      for state, members in sorted(groups.items())} for law in laws}
        modes, screened = screen(jobs, workers=workers,
                                 label=f"{damper.name} cable: each family's start" if progress else None)
    todo = [law for law in laws if law not in screened]
    while todo:  # a round more where a family screened others and did not converge
        for law in todo:
            fit_law(law, {state: m.z for state, m in modes.get(law, {}).items()})
        late = unscreened(screened, {law: all(f.result.converged for f in fits[law].values()) for law in fits})
        again = screen_families({law: modes[law] for law in late}) if late else {}
        screened = {law: v for law, v in screened.items() if law not in late} | again
        todo = [law for law in late if law not in again]
    comparison = compare_families(fits, screened)
    if default:
        partial = any(_remainder(f)[0]["qualifier"] == "partial" for f in fits[comparison["best"]].values())
        law = zoned_candidate(comparison, partial)
        if law is not None and compared_laws((law,), tests):
            top = law[:-len(ZONED_SUFFIX)]  # its uniform family: the zoned fit starts from it
            fit_law(law, {state: zoned_start(f.median(), f.like.prior) for state, f in fits[top].items()})
            comparison = compare_families(fits, screened)
    return fits, comparison

