"""The engine's half-step in numpy: the formulation :func:`sbcal.inference.move_kernel.half_step` compiles.

The same proposals from the same random numbers, for all ensembles at once through stacked arrays (each
ensemble's :class:`sbcal.inference.proposal.MapProposal`, unbent: a test's fit). Kept as the reference of
``tests/test_sampler.py`` and the baseline of ``benchmarks/engine_step.py``; not used by the package.
"""

import numpy as np


def half_step_numpy(coords, s, c, u, jitter, gamma0, independence, normal, chi2, lower, upper,
                    present, mean, chol_t, unwhiten_t, whiten_t, unchol_t, bent, coef, log_norm, t_dof):
    """:func:`sbcal.inference.move_kernel.half_step`, for proposals without a bend (``bent == 0``)."""
    if np.any(bent):
        raise ValueError("the numpy reference covers unbent proposals")
    n_ens, half = s.shape
    ens = np.arange(n_ens)[:, None]
    a = (u[:, 0] * half).astype(int)
    b = (a + 1 + (u[:, 1] * (half - 1)).astype(int)) % half
    gamma = np.where(u[:, 2] < 0.1, 1.0, gamma0 * (1 + 1e-5 * jitter))
    here = coords[s]
    q = here + gamma[..., None] * (coords[c[ens, a]] - coords[c[ens, b]])
    log_u = np.log(u[:, 3])
    tries = normal.shape[1]
    if tries == 0:
        return q, log_u
    shift = coef[:, 0][:, None, None, :]
    v = normal @ chol_t[:, None] * np.sqrt(t_dof / chi2)[..., None] + shift
    drawn = mean[:, None, None, :] + v @ unwhiten_t[:, None]  # (G, T, H, ndim)
    inside = np.all((drawn >= lower) & (drawn <= upper), axis=3)
    first = np.where(inside.any(axis=1), inside.argmax(axis=1), tries - 1)
    drawn = np.take_along_axis(drawn, first[:, None, :, None], axis=1)[:, 0]

    def density(x):
        y = ((x - mean[:, None]) @ whiten_t - coef[:, :1]) @ unchol_t
        return log_norm[:, None] - 0.5 * (t_dof + y.shape[-1]) * np.log1p(np.einsum("gij,gij->gi", y, y) / t_dof)

    chosen = (u[:, 4] < independence) & present[:, None]
    q = np.where(chosen[..., None], drawn, q)
    log_u = np.where(chosen, log_u - (density(here) - density(drawn)), log_u)
    return q, log_u
