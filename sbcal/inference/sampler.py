"""The sampling engine: every posterior in sbcal is drawn here, and this is the only user of emcee.

One entry point, :func:`sample`, takes a *target* — a log-density over named parameters with its
prior — a :class:`SamplerConfig` and a seed, and returns a frozen :class:`SampleResult`. A target is any
picklable object with

- ``prior``: a :class:`sbcal.inference.priors.Prior` (names, boxes, sampled coordinates ``z``);
- ``__call__(z) -> (n,)``: the log-posterior at a batch of sampled coordinates ``(n, ndim)``
  (emcee's ``log_prob`` with ``vectorize=True``), ``-inf`` outside the support;
- optionally ``pointwise_log_likelihood(params) -> (n, n_points)`` with ``params`` by name: then the
  result carries it on the kept draws, for PSIS-LOO.

Steps:

1. **Start**: the posterior mode: the caller's ``start`` polished by L-BFGS-B, or else the best of local
   ascents from a differential-evolution search over the prior box and from the best points of a Sobol design.
2. **Ensembles**: ``n_ensembles`` independent ensembles of walkers, each started from its own seed
   (its walkers drawn from the Laplace approximation at the mode; from each parameter's own
   curvature where the Hessian is not negative definite, a small ball where even that fails) and
   moved within itself (:class:`_Ensembles`) by differential evolution and, in a fraction
   ``independence`` of the proposals, by an independence move: a draw from a proposal fitted to the
   ensemble's own kept steps at the end of the previous round (:mod:`sbcal.inference.proposal`: a
   multivariate t, its narrow directions' centres bent along the widest ones where ``bend`` allows; the
   Laplace approximation in the first round, where it is negative definite). All are held side by side in one
   ``emcee.EnsembleSampler`` so that one vectorised log-density call advances every ensemble
   (``workers > 1`` splits them over processes). Each ensemble draws from its own generator and
   sees only its own steps, so the ensembles are independent chains and the draws do not depend on
   the number of workers.
3. **The convergence policy** (:data:`POLICY`, set in :mod:`sbcal.inference.policy` only): after discarding the first
   ``burn_fraction`` of every chain, the kept run must be at least ``tau_factor`` integrated
   autocorrelation times of every parameter long, and across the ensembles R-hat <= 1.01 and bulk and
   tail ESS >= 400 for every parameter. Rounds continue until it holds or ``max_steps`` (each round
   to the length the autocorrelation asks for, at most doubling the run: the estimate falls as the
   proposals improve); a run that stops at the cap is marked ``converged = False`` with the reason.
   The independence proposals change only between rounds, from the past steps, so every round's
   kernel leaves the posterior invariant (a finite adaptation; what it costs in the first rounds is
   what the burn-in and the diagnostics see).
   **Stranded ensembles**: at the end of a round, an ensemble whose log-densities (median over the round's
   last half) lie more than ``max(25, 3 ndim)`` nats below the best ensemble's sits in a mode with no
   posterior mass (to carry as much as the best one it would need to be ``e^3`` wider in every direction):
   it has not reached the posterior, and no run short of the cap would bring it there (damper1's dry cable
   under ``iwan5_zoned``: one ensemble of four on a short clamp zone 178 nats below, R-hat 1.54 at 8 000
   steps). It is started again from its own draw around the best ensemble's walkers, and the run so far
   becomes warm-up for every ensemble (none of it kept; the cap counts it). At most ``MAX_RESTARTS`` times;
   the result names the ensembles restarted and when.
4. **Draws**: each ensemble is a chain; its draws are its walkers' thinned steps, walker after walker
   (thinned by at least half the largest autocorrelation time, and enough to keep ``max_draws``).
"""

from __future__ import annotations

import math
import time

import emcee
import numpy as np

from ..core.progress import progress_bar
from ..core.workers import one_blas_thread, process_pool
from .move_kernel import half_step, stack_proposals
from .policy import POLICY, SampleResult, SamplerConfig
from .start import capped_cov, find_mode, initial_walkers, laplace
from .proposal import BOX_TRIES, T_DOF, MapProposal, fit_proposal
from .surrogate import fit_surrogate
from .stats import convergence


__all__ = ["POLICY", "MAX_RESTARTS", "SamplerConfig", "SampleResult", "sample", "stranded"]

MAX_RESTARTS = 3
"""Stranded-ensemble restarts a run allows (module docstring)."""


def stranded(per_lp, window: int, ndim: int) -> tuple[list[int], int]:
    """``(lost, best)``: the ensembles stranded in a mode without posterior mass, whose median log-density
    over the last ``window`` steps (``per_lp``: one ``(steps, walkers)`` array per ensemble) lies more than
    ``max(25, 3 ndim)`` nats below that of the best ensemble ``best`` (module docstring)."""
    med = np.array([np.median(lp[-max(window, 1):]) for lp in per_lp])
    return [int(e) for e in np.flatnonzero(med < med.max() - max(25.0, 3.0 * ndim))], int(np.argmax(med))


def _generator(state) -> np.random.Generator:
    """A generator that continues from ``state`` (an ensemble's, as a process hands it back)."""
    rng = np.random.Generator(np.random.PCG64())
    rng.bit_generator.state = state
    return rng


def _restart(target, coords, log_prob, gens, lost, best, nwalkers) -> MapProposal:
    """Walkers of each ensemble in ``lost`` drawn again, from its own generator, around the walkers of the
    ensemble ``best`` (their best point and covariance); ``coords``, ``log_prob`` and ``gens`` updated in
    place. Returns the restarted ensembles' first independence proposal (the t of that approximation)."""
    rows = slice(best * nwalkers, (best + 1) * nwalkers)
    walkers = coords[rows]
    z0 = walkers[np.argmax(log_prob[rows])]
    cov = np.cov(walkers.T) + 1e-12 * np.diag((target.prior.z_upper - target.prior.z_lower) ** 2)
    for e in lost:
        rng = _generator(gens[e])
        mine = slice(e * nwalkers, (e + 1) * nwalkers)
        coords[mine] = initial_walkers(target, z0, cov, nwalkers, rng)
        log_prob[mine] = target(coords[mine])
        gens[e] = rng.bit_generator.state
    return MapProposal.ellipsoid(z0, capped_cov(target.prior, cov))


# --- the ensembles -------------------------------------------------------------------------

class _Ensembles(emcee.moves.Move):
    """Moves for several independent ensembles held side by side in one emcee sampler, so that one
    vectorised log-density call advances all of them.

    Walkers ``[g W, (g + 1) W)`` form ensemble g. Each step, every ensemble splits its walkers in two
    halves at random and moves each half, accepted by Metropolis-Hastings, by

    - differential evolution: ``x + gamma (x_a - x_b)`` with ``x_a != x_b`` drawn from its own other
      half (ter Braak 2006; ``gamma = 2.38 / sqrt(2 ndim)`` with a 1e-5 relative jitter as emcee's
      ``DEMove``, and ``gamma = 1`` in a tenth of the proposals, ter Braak's jump between modes);
    - or, with probability ``independence`` where the ensemble has a proposal, an independence move:
      a draw from that ensemble's proposal (:class:`MapProposal`, fitted by :func:`sample` to the
      ensemble's own earlier steps and fixed for the round; a draw outside the prior box drawn again),
      accepted with the ratio ``p(x') q(x) / (p(x) q(x'))``. Where the posterior is close to its Gaussian approximation it
      decorrelates a walker in a few steps, where differential evolution needs ~4 ndim; where it is
      not (curved beyond the proposal's quadratic bend, several modes), it is mostly rejected and
      differential evolution does the work.

    Where the ensemble has a screen (:mod:`sbcal.inference.surrogate`), a proposal is first accepted or
    rejected on the screen's ratio and the target is called only on those that pass, accepted by the
    corrected ratio (delayed acceptance).

    Every ``redraw[1]``-th step (of this round), each coordinate in ``redraw[0]`` is then redrawn in every walker,
    the others held, accepted with ``p(x') q(x) / (p(x) q(x'))``: an independence move on one coordinate
    (Metropolis-within-Gibbs, exact whatever the target). ``q`` is uniform over the coordinate's box in the sampled
    coordinates, mixed half and half, where ``redraw[2]`` gives the ensemble one, with a uniform over the span its
    kept steps covered in the last round (a tenth of the span beyond either end, within the box; fixed for the
    round, as the independence proposals), and judged first on the ensemble's screen where it has one (delayed
    acceptance, as the other moves: where the coordinate is pinned, most redraws cost no call). It is for a
    parameter the data leave prior-dominated over part of its box: the micro-slip onset below every bench curvature,
    whose flat shoulder beside a narrow core differential evolution crosses in hundreds of steps (``docs/cable.md``,
    "The redraw"). Where ``redraw[2]`` gives an ensemble slopes (``redraw_slant``: the Laplace approximation's in
    the first round, its kept steps' after, fixed for the round), half its walkers move their other coordinates
    with it, ``x_i += b_i (x_j' - x_j)``: the move ``(x, x_j') -> (x', x_j)`` is its own inverse with unit Jacobian
    (a shear), so the ratio is the same, and a redraw follows a ridge along which the others change with it.

    An ensemble never sees another's walkers and draws every random number from its own generator, so
    the ensembles are independent, independently seeded chains: the same as running them one by one,
    in any grouping over processes. Each draws its numbers in a few calls a half-step; one compiled loop
    (:func:`sbcal.inference.move_kernel.half_step`) turns those of all the ensembles into their proposals.
    """

    def __init__(self, n_walkers: int, generators, proposals=None, independence: float = 0.0, box=(None, None),
                 screens=None, redraw=((), 0, None)):
        self.n_walkers, self.generators = n_walkers, list(generators)
        self.redraw_cols, self.redraw_every = tuple(redraw[0]), int(redraw[1])
        self.redraws = list(redraw[2]) if redraw[2] is not None else [None] * len(self.generators)
        self.steps = 0  # steps of this round: when to redraw
        proposals = list(proposals) if proposals is not None else [None] * len(self.generators)
        ndim = next((p.mean.size for p in proposals if p is not None), 0)
        # the proposals as arrays for the compiled moves; independence moves only where there is one
        self.independent = independence > 0 and ndim > 0
        self.stack = stack_proposals(proposals if self.independent else [None] * len(proposals), max(ndim, 1), T_DOF)
        self.screens = list(screens) if screens is not None else [None] * len(self.generators)
        self.calls = 0  # parameter sets the target was called on
        self.independence = independence
        # the prior box (lower, upper) in the sampled coordinates: where a draw is worth proposing
        self.box = tuple(np.full(max(ndim, 1), v) if b is None else np.asarray(b, float)
                         for b, v in zip(box, (-np.inf, np.inf)))

    def propose(self, model, state):
        coords, w = state.coords, self.n_walkers
        n_ens, half, ndim = len(self.generators), w // 2, coords.shape[1]
        tries = BOX_TRIES + 1 if self.independent else 0
        # each ensemble's random numbers from its own generator, a few calls each, into arrays that one
        # compiled loop turns into every ensemble's proposals (as numpy, a step was ~40 small calls a half)
        u = np.empty((n_ens, 6, half))  # the kernel's five uniforms, and stage 2's threshold (with a screen)
        jitter = np.empty((n_ens, half))
        normal = np.empty((n_ens, tries, half, ndim))
        chi2 = np.empty((n_ens, tries, half))
        perms = np.stack([rng.permutation(w) for rng in self.generators]) + w * np.arange(n_ens)[:, None]
        accepted = np.zeros(len(coords), dtype=bool)
        for h in (0, 1):
            s, c = (perms[:, :half], perms[:, half:]) if h == 0 else (perms[:, half:], perms[:, :half])
            for e, (rng, sg) in enumerate(zip(self.generators, self.screens)):
                rng.random(out=u[e, :6 if sg is not None else 5])
                rng.standard_normal(out=jitter[e])
                if tries:
                    rng.standard_normal(out=normal[e])
                    rng.standard_gamma(T_DOF / 2, out=chi2[e])  # chi-square / 2
            q, log_u = half_step(coords, s, c, u, jitter, 2.38 / np.sqrt(2 * ndim), self.independence,
                                 normal, 2 * chi2, *self.box, *self.stack)
            go = np.ones((n_ens, half), bool)
            for e, sg in enumerate(self.screens):
                if sg is not None:
                    go[e], log_u[e] = _screened(sg, q[e], coords[s[e]], log_u[e], u[e, 5])
            idx, q, log_u = s[go], q[go], log_u[go]
            if not len(idx):
                continue
            # the target itself, not emcee's wrapper of it (its per-value checks cost as much as the model)
            new_lp = np.asarray(model.log_prob_fn(q), dtype=float)
            if np.isnan(new_lp).any():
                raise ValueError("the log-probability returned NaN")
            self.calls += len(idx)
            ok = new_lp - state.log_prob[idx] > log_u
            coords[idx[ok]], state.log_prob[idx[ok]] = q[ok], new_lp[ok]
            accepted[idx[ok]] = True
        self.steps += 1
        if self.redraw_every and self.redraw_cols and self.steps % self.redraw_every == 0:
            for k, j in enumerate(self.redraw_cols):
                self._redraw(model, state, accepted, k, j)
        return state, accepted

    def _redraw(self, model, state, accepted, k: int, j: int):
        """Coordinate ``j`` (the ``k``-th redrawn) of every walker redrawn, accepted by Metropolis-Hastings (first on
        the ensemble's screen where it has one, as the other moves)."""
        w, coords = self.n_walkers, state.coords
        lo, hi = self.box[0][j], self.box[1][j]
        q = coords.copy()
        log_u = np.empty(len(q))
        go = np.ones(len(q), bool)
        for e, (rng, fitted, sg) in enumerate(zip(self.generators, self.redraws, self.screens)):
            span, slopes = fitted if fitted is not None else (None, None)
            rows = slice(e * w, (e + 1) * w)
            new = rng.uniform(lo, hi, size=w)
            if span is not None:  # half from the span of the kept steps
                a, b = span[k]
                new = np.where(rng.random(w) < 0.5, new, rng.uniform(a, b, size=w))

                def log_q(v):
                    return np.log(0.5 / (hi - lo) + np.where((v >= a) & (v <= b), 0.5 / (b - a), 0.0))

                log_u[rows] = np.log(rng.random(w)) + log_q(new) - log_q(coords[rows, j])
            else:
                log_u[rows] = np.log(rng.random(w))
            if slopes is not None:  # half the walkers' other coordinates follow along the ridge
                along = rng.random(w) < 0.5
                q[rows] += np.where(along, new - coords[rows, j], 0.0)[:, None] * slopes[k]
            q[rows, j] = new
            if sg is not None:
                go[rows], log_u[rows] = _screened(sg, q[rows], coords[rows], log_u[rows], rng.random(w))
        idx = np.flatnonzero(go)
        if not idx.size:
            return
        new_lp = np.asarray(model.log_prob_fn(q[idx]), dtype=float)
        if np.isnan(new_lp).any():
            raise ValueError("the log-probability returned NaN")
        self.calls += idx.size
        ok = new_lp - state.log_prob[idx] > log_u[idx]
        coords[idx[ok]], state.log_prob[idx[ok]] = q[idx[ok]], new_lp[ok]
        accepted[idx[ok]] = True


def _screened(screen, proposed, current, log_u, u):
    """Delayed acceptance's first stage: ``(go, threshold)`` — the proposals that pass on ``screen``'s ratio against
    the Metropolis-Hastings threshold ``log_u``, and the second stage's threshold on the target's ratio, which
    carries the screen's (``log u + ds``, with fresh uniforms ``u``)."""
    ds = screen(np.concatenate([proposed, current]))
    ds = ds[:len(proposed)] - ds[len(proposed):]
    go = ds > log_u
    return go, np.log(u) + np.where(go, ds, 0.0)


def _redraw_proposal(kept, cols, lower, upper, slant: bool) -> tuple[np.ndarray, np.ndarray | None]:
    """The redraw's proposal for one ensemble (:class:`_Ensembles`) from its kept steps ``(steps, walkers, ndim)``:
    ``(span, slopes)``. ``span`` ``(k, 2)``: the span each redrawn coordinate ``cols`` covered, a tenth of it beyond
    either end, within its box ``lower``-``upper`` (arrays over ``cols``). ``slopes`` ``(k, ndim)``: the least-squares
    slope of every coordinate on each redrawn one (0 on the redrawn coordinates themselves), the ridge a slanted
    redraw moves along; None without ``slant``."""
    x = kept.reshape(-1, kept.shape[-1])
    sub = x[:, cols]
    a, b = sub.min(axis=0), sub.max(axis=0)
    pad = 0.1 * (b - a) + 1e-9 * (upper - lower)
    span = np.column_stack([np.maximum(a - pad, lower), np.minimum(b + pad, upper)])
    return span, _slopes(np.cov(x.T), cols) if slant else None


def _slopes(cov, cols) -> np.ndarray:
    """``(k, ndim)``: the slope of every coordinate on each of the ``k`` coordinates ``cols`` under the covariance
    ``cov`` (``cov[:, j] / cov[j, j]``), 0 on ``cols`` themselves: the ridge a slanted redraw moves along."""
    cov = np.atleast_2d(cov)
    var = np.diag(cov)[cols]
    slopes = cov[cols] / np.where(var > 0, var, np.inf)[:, None]
    slopes[:, cols] = 0.0
    return slopes


def _advance(job):
    """Run some ensembles (side by side) ``steps`` further; module-level so a process can run it.

    ``job = (target, coords (G W, ndim), log_prob (G W,), generator states (G,), proposals (G,),
    independence, steps, screens (G,), redraw_every, the redraw's (span, slopes) (G,))``; returns the chain, the log-probabilities, the final coords/log-probs,
    the generators' states, the acceptance counts per walker and the parameter sets the target was called on.
    """
    target, coords, log_prob, gen_states, proposals, independence, steps, screens, redraw_every, redraws = job
    generators = [_generator(st) for st in gen_states]
    n, ndim = coords.shape
    prior = target.prior
    redraw = ([prior.names.index(nm) for nm in prior.redrawn], redraw_every, redraws)
    move = _Ensembles(n // len(generators), generators, proposals, independence,
                      (prior.z_lower, prior.z_upper), screens, redraw)
    sampler = emcee.EnsembleSampler(n, ndim, target, vectorize=True, moves=[move])
    with one_blas_thread():
        state = sampler.run_mcmc(emcee.State(coords, log_prob=log_prob), steps, progress=False)
    return (sampler.get_chain(), sampler.get_log_prob(), state.coords, state.log_prob,
            [g.bit_generator.state for g in generators], sampler.backend.accepted.copy(), move.calls)


def _tau(chain) -> tuple[np.ndarray, int]:
    """Integrated autocorrelation time of each parameter of one ensemble's chain ``(steps, walkers, ndim)``
    (emcee's estimator over the walkers that moved), and the number of walkers that never moved."""
    moving = np.ptp(chain, axis=0).max(axis=1) > 0  # (walkers,)
    if not moving.any():
        return np.full(chain.shape[-1], np.inf), chain.shape[1]
    # a walker moved only by redraws of other coordinates keeps this one constant: its acf is 0/0, the
    # coordinate's tau NaN, read as inf (not converged this round) without numpy's warning on stderr
    with np.errstate(invalid="ignore", divide="ignore"):
        tau = emcee.autocorr.integrated_time(chain[:, moving], c=5, tol=0, quiet=True)
    return np.where(np.isfinite(tau), tau, np.inf), int((~moving).sum())


def _draws(chains, lps, burn, thin):
    """Kept, thinned draws of every ensemble: ``(n_chains, n_draws, ndim)`` walker-major, and log-probs."""
    x = np.stack([np.swapaxes(c[burn::thin], 0, 1).reshape(-1, c.shape[-1]) for c in chains])
    lp = np.stack([lp[burn::thin].T.reshape(-1) for lp in lps])
    return x, lp


def _assess(chains, lps, n, names, config, to_natural):
    """``(done, reason, tau, thin, draws, lp, diagnostics, need)`` after ``n`` steps of every ensemble."""
    burn = int(config.burn_fraction * n)
    kept = n - burn
    estimates = [_tau(c[burn:]) for c in chains]
    tau = np.max([t for t, _ in estimates], axis=0)  # (ndim,): the worst ensemble
    stuck = sum(k for _, k in estimates)
    finite = np.isfinite(tau).all()
    need = int(math.ceil(config.tau_factor * tau.max() / (1 - config.burn_fraction))) if finite else config.max_steps
    nwalkers = chains[0].shape[1]
    thin = max(1, int(math.ceil(tau.max() / 2)) if finite else 1, int(math.ceil(kept * nwalkers / config.max_draws)))
    x, lp = _draws(chains, lps, burn, thin)
    # on the natural-unit draws that are stored (the folded R-hat is not invariant under log)
    natural = to_natural(x.reshape(-1, x.shape[-1])).reshape(x.shape)
    diag = convergence({nm: natural[:, :, i] for i, nm in enumerate(names)})
    problems = []
    if stuck:
        problems.append(f"{stuck} walker(s) never moved in the kept run")
    if kept < config.tau_factor * tau.max():
        worst = names[int(np.argmax(tau))]
        problems.append(f"run {kept} steps < {config.tau_factor:g} x tau ({worst}: tau {tau.max():.0f})")
    for nm, d in diag.items():
        if not d["r_hat"] <= POLICY["rhat_max"]:
            problems.append(f"R-hat of {nm} {d['r_hat']:.3f} > {POLICY['rhat_max']}")
        ess = min(d["ess_bulk"], d["ess_tail"])
        if not ess >= POLICY["ess_min"]:
            problems.append(f"ESS of {nm} {ess:.0f} < {POLICY['ess_min']:.0f}")
    return not problems, "; ".join(problems), dict(zip(names, map(float, tau))), burn, thin, x, lp, diag, need


def sample(target, *, seed: int, config: SamplerConfig = SamplerConfig(), start=None,
           progress: str | None = None) -> SampleResult:
    """Sample the posterior of ``target`` under sbcal's convergence policy.

    Parameters
    ----------
    target : object
        ``prior``, vectorised ``__call__(z)`` and optionally ``pointwise_log_likelihood(params)``
        (module docstring).
    seed : int or numpy.random.SeedSequence
        Seeds the start and every ensemble: the same seed gives the same draws, whatever
        ``config.workers``.
    config : SamplerConfig
    start : dict of str -> float, or ndarray of shape (ndim,), optional
        Where to polish the mode from (natural values by name, or sampled coordinates); default a
        differential-evolution search over the prior box.
    progress : str, optional
        A label: a progress bar on stderr (when it is a terminal).

    Returns
    -------
    SampleResult
    """
    t0 = time.perf_counter()
    prior = target.prior
    names = tuple(prior.names)
    nwalkers = max(config.nwalkers, 2 * prior.ndim + 2)
    nwalkers += nwalkers % 2
    root = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    seqs = root.spawn(config.n_ensembles + 1)
    with progress_bar(progress, total=None, unit="step") as bar:
        bar.set_postfix_str("finding the mode")
        z0 = find_mode(target, start, np.random.default_rng(seqs[0]), config)
        cov, full = laplace(target, z0)
        coords, gens = [], []
        for ss in seqs[1:]:  # each ensemble: its own start and its own generator
            rng = np.random.default_rng(ss)
            coords.append(initial_walkers(target, z0, cov, nwalkers, rng))
            gens.append(rng.bit_generator.state)
        coords = np.concatenate(coords)
        log_prob = target(coords)
        # the ensembles are cut into one group per process; the draws do not depend on the cut
        groups = np.array_split(np.arange(config.n_ensembles), min(max(config.workers, 1), config.n_ensembles))
        chains, lps = [], []
        accepted = np.zeros(len(coords))
        n, block = 0, min(config.first_steps, config.max_steps)
        # the first round's independence proposal: the Laplace approximation at the mode
        first = MapProposal.ellipsoid(z0, capped_cov(prior, cov)) if full else None
        proposals = [first] * config.n_ensembles
        screens = [None] * config.n_ensembles
        # the redraw's proposals (:class:`_Ensembles`): the first round's slopes from the Laplace approximation
        redrawn = [names.index(nm) for nm in prior.redrawn] if config.redraw_every else []
        redraws = [(None, _slopes(cov, redrawn)) if redrawn and config.redraw_slant and cov is not None else None]
        redraws *= config.n_ensembles  # no Laplace covariance (a flat direction at the start): no slopes yet
        calls, spent, restarts = 0, 0, []  # spent: warm-up steps before the last restart
        with process_pool(len(groups)) as pool:
            while True:
                jobs = []
                for grp in groups:
                    rows = np.concatenate([np.arange(e * nwalkers, (e + 1) * nwalkers) for e in grp])
                    jobs.append((target, coords[rows], log_prob[rows], [gens[e] for e in grp],
                                 [proposals[e] for e in grp], config.independence, block,
                                 [screens[e] for e in grp], config.redraw_every, [redraws[e] for e in grp]))
                pieces_c, pieces_l = [], []
                for grp, (c, lp, cs, ls, gs, acc, k) in zip(groups, pool.map(_advance, jobs) if pool else map(_advance, jobs)):
                    rows = np.concatenate([np.arange(e * nwalkers, (e + 1) * nwalkers) for e in grp])
                    coords[rows], log_prob[rows] = cs, ls
                    for e, st in zip(grp, gs):
                        gens[e] = st
                    accepted[rows] += acc
                    calls += k
                    pieces_c.append(c)
                    pieces_l.append(lp)
                chains.append(np.concatenate(pieces_c, axis=1))  # (steps, ensembles x walkers, ndim)
                lps.append(np.concatenate(pieces_l, axis=1))
                n += block
                chain = np.concatenate(chains)
                lp_all = np.concatenate(lps)
                per = [chain[:, e * nwalkers:(e + 1) * nwalkers] for e in range(config.n_ensembles)]
                per_lp = [lp_all[:, e * nwalkers:(e + 1) * nwalkers] for e in range(config.n_ensembles)]
                done, reason, tau, burn, thin, x, lp, diag, need = _assess(per, per_lp, n, names, config,
                                                                           prior.to_natural)
                bar.total = spent + max(need, n)  # warm-up before a restart included
                bar.update(block)
                bar.set_postfix_str(f"tau {max(tau.values()):.0f}")
                if done or spent + n >= config.max_steps:
                    break
                lost, best = stranded(per_lp, block // 2, prior.ndim) if len(restarts) < MAX_RESTARTS else ([], 0)
                # the next round: to the length the autocorrelation asks for (5 % beyond, as the estimate
                # grows with the run), or half again when only R-hat or ESS are short
                more = int(math.ceil(1.05 * need)) - n if need > n else n // 2
                # at most doubling the run: the estimate of tau falls as the proposals improve
                block = min(max(more, n // 10, 50), n, config.max_steps - spent - n)
                if config.independence > 0:  # each ensemble's proposal from its own kept steps
                    proposals = [fit_proposal(c[burn:], config.bend) for c in per]
                if redrawn:
                    redraws = [_redraw_proposal(c[burn:], redrawn, prior.z_lower[redrawn], prior.z_upper[redrawn],
                                                config.redraw_slant) for c in per]
                if config.screen:
                    box = (prior.z_lower, prior.z_upper)
                    screens = [fit_surrogate(c[burn:], lp_e[burn:], box, tp)
                               for c, lp_e, tp in zip(per, per_lp, proposals)]
                if lost:  # started again; the run so far is every ensemble's warm-up
                    fresh = _restart(target, coords, log_prob, gens, lost, best, nwalkers)
                    for e in lost:
                        proposals[e], screens[e], redraws[e] = fresh, None, None
                    restarts.append((tuple(lost), spent + n))
                    spent += n
                    chains, lps, n = [], [], 0
                    accepted[:] = 0
                    block = min(config.first_steps, config.max_steps - spent)
    natural = prior.to_natural(x.reshape(-1, prior.ndim))
    params = {nm: natural[:, i] for i, nm in enumerate(names)}
    loglik = None
    if hasattr(target, "pointwise_log_likelihood"):
        chunk = 2000
        parts = [target.pointwise_log_likelihood({k: v[i:i + chunk] for k, v in params.items()})
                 for i in range(0, natural.shape[0], chunk)]
        loglik = np.concatenate(parts).reshape(x.shape[0], x.shape[1], -1)
    return SampleResult(
        names=names, draws={nm: v.reshape(x.shape[:2]) for nm, v in params.items()}, log_prob=lp, log_likelihood=loglik,
        tau=tau, acceptance=accepted.reshape(config.n_ensembles, nwalkers).mean(axis=1) / n, r_hat={k: v["r_hat"] for k, v in diag.items()},
        ess_bulk={k: v["ess_bulk"] for k, v in diag.items()}, ess_tail={k: v["ess_tail"] for k, v in diag.items()},
        n_steps=n, burn=burn, thin=thin, converged=bool(done),
        reason="" if done else f"stopped at the {config.max_steps}-step cap: {reason}",
        start={nm: float(v) for nm, v in zip(names, prior.to_natural(z0[None])[0])},
        wall_s=time.perf_counter() - t0, config=config, calls=int(calls),
        restarts=tuple((e, step) for lost, step in restarts for e in lost),
        sampled_as=prior.as_dict().get("sampled_as"), redrawn=prior.redrawn,
    )
