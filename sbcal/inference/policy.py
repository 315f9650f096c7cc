"""The sampling engine's rule, settings and result (:mod:`sbcal.inference.sampler` draws with them; it re-exports
them): :data:`POLICY`, the convergence rule; :class:`SamplerConfig`, a run's settings, stored with it;
:class:`SampleResult`, a posterior's draws by name and how they were made."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from ..core.workers import default_workers

__all__ = ["POLICY", "SamplerConfig", "SampleResult"]

POLICY = {"min_ensembles": 4, "rhat_max": 1.01, "ess_min": 400.0, "tau_factor": 50.0}
"""sbcal's convergence rule. A configuration may be stricter; a looser ``tau_factor`` needs a stated
reason (``SamplerConfig.tau_reason``), which every result carries into its output."""



@dataclass(frozen=True)
class SamplerConfig:
    """Sampler settings (stored with every run).

    Attributes
    ----------
    nwalkers : int
        Walkers per ensemble (raised to ``2 ndim + 2`` where needed, and to an even number).
    n_ensembles : int
        Independently seeded ensembles, the chains of R-hat (at least ``POLICY["min_ensembles"]``).
    tau_factor : float
        The kept run must be this many autocorrelation times long (``POLICY["tau_factor"]``; less
        only with ``tau_reason``).
    tau_reason : str
        Why a looser ``tau_factor`` is acceptable here; shown wherever the result is reported.
    burn_fraction : float
        Fraction of each chain discarded as burn-in.
    first_steps : int
        Steps of the first round (then rounds are sized from the autocorrelation estimate).
    max_steps : int
        Cap on steps per ensemble; a run that stops there is not converged.
    max_draws : int
        Draws kept per ensemble (the thinning grows to keep at most this many).
    de_population, de_generations : int
        The differential-evolution search for the start (when the caller gives none).
    workers : int
        Processes for the ensembles (the draws do not depend on it); 1 runs them in this process.
    independence : float
        From the second round on, the fraction of proposals drawn independently of the walker from a
        proposal fitted to the ensemble's own kept steps (:class:`sbcal.inference.sampler._Ensembles`); 0 moves
        by differential evolution alone.
    bend : int
        How many of the posterior's widest directions the independence proposal may bend its narrow ones
        along (:class:`sbcal.inference.proposal.MapProposal`; chosen per round on held-out steps, 0 where a
        bend does not pay); 0,
        the default, proposes from the multivariate t alone. A cable state's fit bends (a weakly determined
        law is a thin curved ridge); a test's few parameters do not (measured: a bound-hugging damping
        parameter's autocorrelation grew 3x with the bend).
    screen : bool
        From the second round on, judge each proposal first by a quadratic of the log-density fitted to the
        ensemble's kept steps, and call the target only on those that pass (delayed acceptance,
        :mod:`sbcal.inference.surrogate`: exact whatever the quadratic; per ensemble and round, used only
        where it predicts held-out steps). For targets whose call costs milliseconds per set (a cable state).
    redraw_every : int
        Every this many steps, each parameter the target's prior names in ``redrawn``
        (:attr:`sbcal.inference.priors.Prior.redrawn`) is redrawn in every walker, from its box and the span of the
        ensemble's kept steps, accepted by Metropolis-Hastings (Metropolis-within-Gibbs;
        :class:`sbcal.inference.sampler._Ensembles`); 0 never.
    redraw_slant : bool
        Half the walkers of a redraw move the other coordinates with the redrawn one, by their slopes on it (the
        Laplace approximation's in the first round, the ensemble's kept steps' after; a shear, exact), the other
        half hold them (the default); False: every walker holds them. It halves the autocorrelation where an onset
        the bench sees drags the others along (``docs/cable.md``, "The slanted redraw"), takes every bundled cable
        fit to convergence in fewer steps and costs ``sbcal run`` nothing measurable (596 s against 591 s in one
        hour). It acts only where the prior names parameters ``redrawn`` (the cable laws' onsets).
    """

    nwalkers: int = 24
    n_ensembles: int = 4
    tau_factor: float = POLICY["tau_factor"]
    tau_reason: str = ""
    burn_fraction: float = 0.2
    first_steps: int = 400
    max_steps: int = 20000
    max_draws: int = 1000
    de_population: int = 48
    de_generations: int = 150
    workers: int = field(default_factory=default_workers)
    independence: float = 0.5
    bend: int = 0
    screen: bool = False
    redraw_every: int = 2
    redraw_slant: bool = True

    def __post_init__(self):
        if self.n_ensembles < POLICY["min_ensembles"]:
            raise ValueError(f"n_ensembles {self.n_ensembles}: the policy needs >= {POLICY['min_ensembles']}")
        if self.tau_factor < POLICY["tau_factor"] and not self.tau_reason:
            raise ValueError(f"tau_factor {self.tau_factor} < {POLICY['tau_factor']} needs a stated tau_reason")
        if not 0 <= self.burn_fraction < 1 or self.first_steps < 1 or self.max_steps < self.first_steps:
            raise ValueError("burn_fraction in [0, 1), 1 <= first_steps <= max_steps")
        if self.bend < 0:
            raise ValueError(f"bend {self.bend}: a number of directions, >= 0")
        if not 0 <= self.independence < 1:
            raise ValueError(f"independence {self.independence}: a fraction in [0, 1)")
        if self.redraw_every < 0:
            raise ValueError(f"redraw_every {self.redraw_every}: a number of steps, >= 0 (0: never)")

    def policy(self) -> str:
        """The rule this configuration applies, in words (stored and shown with every result)."""
        text = (f">= {self.n_ensembles} independently seeded ensembles, R-hat <= {POLICY['rhat_max']} and bulk "
                f"and tail ESS >= {POLICY['ess_min']:.0f} for every parameter, run >= {self.tau_factor:g} "
                f"autocorrelation times (at most {self.max_steps} steps)")
        return text + (f"; {self.tau_factor:g} tau because {self.tau_reason}" if self.tau_reason else "")


@dataclass(frozen=True)
class SampleResult:
    """A posterior: draws by parameter name and how they were made.

    Attributes
    ----------
    names : tuple of str
        Parameters, in the prior's (canonical) order.
    draws : dict of str -> ndarray, shape (n_chains, n_draws)
        Natural units; a chain is one ensemble, its draws its walkers' thinned steps, walker after walker.
    log_prob : ndarray, shape (n_chains, n_draws)
    log_likelihood : ndarray, shape (n_chains, n_draws, n_points), or None
        The target's pointwise log-likelihood at the draws (when it has one).
    tau : dict of str -> float
        Integrated autocorrelation time [steps], the largest over the ensembles.
    acceptance : ndarray, shape (n_chains,)
        Mean acceptance fraction of each ensemble.
    r_hat, ess_bulk, ess_tail : dict of str -> float
        Across the chains (rank-normalised split R-hat; ArviZ's bulk and tail ESS).
    n_steps, burn, thin : int
        Steps per ensemble, of which the first ``burn`` are discarded; kept steps thinned by ``thin``.
    converged : bool
    reason : str
        Why not converged ('' when converged).
    start : dict of str -> float
        Where the ensembles started (the polished mode).
    wall_s : float
    config : SamplerConfig
    calls : int
        Parameter sets the target was called on by the ensembles' moves (the start's and the stored
        draws' pointwise log-likelihood not counted): with ``config.screen``, fewer than the proposals.
    restarts : tuple of (int, int)
        ``(ensemble, step)`` of each stranded ensemble started again (module docstring); the steps
        before the last are warm-up, not in ``n_steps``.
    sampled_as : list of dict, optional
        The target's moved coordinates where its prior has shears (:meth:`sbcal.inference.priors.Prior.as_dict`'s
        ``sampled_as``): the coordinates the chains, their autocorrelation and R-hat were in.
    redrawn : tuple of str
        The parameters the target's prior names redrawn (every ``config.redraw_every`` steps;
        :class:`sbcal.inference.sampler._Ensembles`).
    """

    names: tuple
    draws: dict
    log_prob: np.ndarray
    log_likelihood: np.ndarray | None
    tau: dict
    acceptance: np.ndarray
    r_hat: dict
    ess_bulk: dict
    ess_tail: dict
    n_steps: int
    burn: int
    thin: int
    converged: bool
    reason: str
    start: dict
    wall_s: float
    config: SamplerConfig
    calls: int = 0
    restarts: tuple = ()
    sampled_as: list | None = None
    redrawn: tuple = ()

    @property
    def n_chains(self) -> int:
        return self.log_prob.shape[0]

    def flat(self) -> dict:
        """Draws pooled over chains: ``{name: (n_chains * n_draws,)}``."""
        return {n: v.reshape(-1) for n, v in self.draws.items()}

    def quantiles(self, name: str, q=(0.05, 0.5, 0.95)) -> np.ndarray:
        return np.quantile(self.draws[name], q)

    @property
    def r_hat_max(self) -> float:
        return float(max(self.r_hat.values()))

    @property
    def ess_bulk_min(self) -> float:
        return float(min(self.ess_bulk.values()))

    @property
    def ess_tail_min(self) -> float:
        return float(min(self.ess_tail.values()))

    def convergence_dict(self) -> dict:
        """What JSON outputs carry about convergence."""
        return {"converged": self.converged, "reason": self.reason, "r_hat_max": self.r_hat_max,
                "ess_bulk_min": self.ess_bulk_min, "ess_tail_min": self.ess_tail_min,
                "tau_max": float(max(self.tau.values())), "n_steps": self.n_steps, "n_chains": self.n_chains,
                "restarts": [list(r) for r in self.restarts], "policy": self.config.policy(),
                **({"sampled_as": self.sampled_as} if self.sampled_as else {}),
                **({"redrawn": list(self.redrawn)} if self.redrawn and self.config.redraw_every else {})}

    def config_dict(self) -> dict:
        return asdict(self.config)
