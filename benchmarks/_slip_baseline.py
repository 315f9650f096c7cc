"""The one-element strand-slip model of sbcal 0.1 (before the distributed cable), kept only as the
speed baseline of ``benchmarks/cable.py`` ("today's one-element arms" of issue 13): each arm one
element at its rms curvature, a rational softening law solved by 12 Illinois steps."""

from dataclasses import dataclass

import numpy as np

from sbcal.model.damper import Damper
from sbcal.model.fem import arm_impedance, arm_kernel

_SLIP_ITERATIONS = 12
_GEOMETRY = ("a1", "a2")


def _col(v):
    return np.asarray(v, dtype=float).reshape(-1, 1)


@dataclass(frozen=True)
class SlipModel:
    """The strand-slip forward model at given commanded amplitudes (picklable, for the sampler).

    ``SlipModel(amplitude_mm_pp)(damper, freq_hz, **params) -> complex (n, n_freq)``, parameters
    ``EJ_slip, EJ_stick`` [N m^2], ``chi_slip`` [1/m], ``slip_exponent``, ``beta_material``,
    ``beta_friction`` and optionally ``a1, a2`` [m], each scalar or (n,).

    Per arm e and line, with the clamp driven at ``X0 = amplitude / 2`` and the arm's rms curvature
    amplitude over its length ``chi_e`` (the Hermite element's curvature is linear along it)::

        g = 1 / (1 + (chi_e / chi_slip)^k)
        EJ_e = EJ_slip + (EJ_stick - EJ_slip) g,   beta_e = beta_material + beta_friction (1 - g)

    solved self-consistently (the curvature depends on ``EJ_e``) for the stick fraction ``g`` in
    [0, 1] by a bracketing root finder (12 Illinois steps), a fixed number of steps so that the model is a deterministic
    function of its parameters. ``EJ_slip >= EJ_stick`` is outside the model (NaN).

    Attributes
    ----------
    amplitude_mm_pp : ndarray, shape (n_freq,)
        Commanded base amplitude per line [mm peak-to-peak].
    """

    amplitude_mm_pp: np.ndarray

    def state(self, damper: Damper, freq_hz, *, EJ_slip, EJ_stick, chi_slip, slip_exponent, beta_material,
              beta_friction, **params):
        """Per-arm rigidity and loss factor ``(ej, beta)``, each (2 arms, n, n_freq), and the rms curvature."""
        f = np.asarray(freq_hz, dtype=float)
        omega = 2 * np.pi * f[None, :]
        x0 = np.broadcast_to(np.asarray(self.amplitude_mm_pp, dtype=float), f.shape)[None, :] / 2 * 1e-3
        geometry = {k: params[k] for k in _GEOMETRY if k in params}
        kernel = arm_kernel(damper, **geometry)
        lo, hi, c0, k = (_col(v)[None] for v in (EJ_slip, EJ_stick, chi_slip, slip_exponent))
        bm, bf = _col(beta_material)[None], _col(beta_friction)[None]
        n = max(lo.shape[1], hi.shape[1], c0.shape[1], k.shape[1], bm.shape[1], bf.shape[1],
                *(np.size(v) for v in geometry.values()))
        shape = (2, n, f.size)

        def gap(g):
            """``g - G(g)``: the stick fraction in, minus the one the resulting curvature gives."""
            ej, beta = lo + (hi - lo) * g, bm + bf * (1 - g)
            chi = kernel.curvatures(omega, ej * (1 + 1j * beta), x0, 0.0)  # (n, F, arm, end)
            a, b = chi[..., 0], chi[..., 1]
            rms = np.sqrt(np.maximum((np.abs(a)**2 + np.abs(b)**2 + np.real(a * np.conj(b))) / 3, 0.0))
            rms = np.moveaxis(rms, -1, 0)  # (2, n, F)
            return g - 1.0 / (1.0 + (rms / c0) ** k), rms

        # The fixed point is one scalar g in [0, 1] per arm and line, bracketed: gap(0) < 0 <= gap(1).
        # Illinois regula falsi, a fixed number of steps, so the model is a deterministic function of
        # its parameters (plain iteration converges slowly or oscillates near the resonances).
        g0, g1 = np.zeros(shape), np.ones(shape)
        h0, h1 = gap(g0)[0], gap(g1)[0]
        side = np.zeros(shape)
        for _ in range(_SLIP_ITERATIONS):
            denom = h1 - h0
            g = np.where(denom > 0, (g0 * h1 - g1 * h0) / np.where(denom > 0, denom, 1.0), g1)
            h, rms = gap(g)
            left = h < 0
            g0, h0 = np.where(left, g, g0), np.where(left, h, h0)
            g1, h1 = np.where(left, g1, g), np.where(left, h1, h)
            # Illinois: the end kept twice in a row has its value halved (no one-sided stall)
            h1 = np.where(left & (side == 1), 0.5 * h1, h1)
            h0 = np.where(~left & (side == -1), 0.5 * h0, h0)
            side = np.where(left, 1, -1)
        g = np.where(np.abs(h0) < np.abs(h1), g0, g1)
        ln_ej, beta = np.log(lo + (hi - lo) * g), bm + bf * (1 - g)
        return np.exp(ln_ej), beta, rms

    def __call__(self, damper: Damper, freq_hz, **params):
        ej, beta, _ = self.state(damper, freq_hz, **params)
        geometry = {k: params[k] for k in _GEOMETRY if k in params}
        out = arm_impedance(damper, freq_hz, ej1=ej[0], ej2=ej[1], beta1=beta[0], beta2=beta[1], **geometry)[..., 0, 0]
        bad = (_col(params["EJ_slip"]) >= _col(params["EJ_stick"]))
        return np.where(bad, np.nan, out)


