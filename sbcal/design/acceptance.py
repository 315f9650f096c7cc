"""The acceptance file of ``sbcal compare``: what the purchaser and the supplier agreed.

IEC 61897 (the type test of Stockbridge dampers) runs the characteristic test before and after the
fatigue test and leaves the tolerances on the change to the purchaser and the supplier. The file says
which quantities, by how much, at which excitation and over which frequency range (``docs/compare.md``)::

    same_design = true          # refuse two runs of different damper geometry (default: warn)

    [excitation]
    velocity_m_s = 0.1          # constant clamp velocity (IEC 61897's characteristic test) ...
    # amplitude_mm_pp = 1.0     # ... or a constant clamp amplitude [mm p-p], not both
    frequency_hz = [5.0, 40.0]  # the range the criteria apply over

    [tolerance]                 # each optional; at least one
    resonance_frequency_pct = 5.0   # every resonance's frequency within +-5 %
    resonance_power_pct = 20.0      # the power dissipated at every resonance within +-20 %
    impedance_pct = 20.0            # |Z| at every line in the range within +-20 %
    phase_deg = 10.0                # the impedance phase at every line within +-10 deg
    power_pct = 30.0                # the power dissipated at every line within +-30 %

Every key is checked: an unknown one, a tolerance <= 0 or a range that is not two increasing
frequencies ends in one line naming the file and the key.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from ..core._io import read_toml
from ..core.errors import InputError


__all__ = ["TOLERANCES", "Acceptance", "read_acceptance", "default_acceptance"]

TOLERANCES = {
    "resonance_frequency_pct": "resonance frequency",
    "resonance_power_pct": "power at resonance",
    "impedance_pct": "impedance |Z|",
    "phase_deg": "impedance phase",
    "power_pct": "power dissipated",
}
"""The criteria an acceptance file may set, and their names in the output."""

_EXCITATION = ("velocity_m_s", "amplitude_mm_pp", "frequency_hz")
_TOP = ("excitation", "tolerance", "same_design", "name", "description")


@dataclass(frozen=True)
class Acceptance:
    """The agreed characteristic test and tolerances.

    Attributes
    ----------
    mode : str
        ``"velocity"`` (constant clamp velocity) or ``"amplitude"`` (constant clamp amplitude).
    level : float or None
        The velocity [m/s] or the amplitude [mm p-p]; None: each constant-amplitude test the two runs
        share (a comparison without a file).
    freq_range_hz : tuple of float or None
        (lowest, highest) [Hz]; None: the lines both runs measured.
    tolerances : dict
        Key of :data:`TOLERANCES` -> tolerance (% or deg); empty: the change without a decision.
    same_design : bool
        Two runs of different damper geometry are refused (else a warning).
    source : str
        The file, or ``""``.
    """

    mode: str = "amplitude"
    level: float | None = None
    freq_range_hz: tuple | None = None
    tolerances: dict = field(default_factory=dict)
    same_design: bool = False
    source: str = ""

    @property
    def decides(self) -> bool:
        """The file sets tolerances: a decision is made."""
        return bool(self.tolerances)

    def as_dict(self) -> dict:
        return {"mode": self.mode, "level": self.level,
                "freq_range_hz": list(self.freq_range_hz) if self.freq_range_hz else None,
                "tolerances": dict(self.tolerances), "same_design": self.same_design, "source": self.source}


def default_acceptance() -> Acceptance:
    """No file: the change at each constant amplitude both runs tested, over their common lines, no decision."""
    return Acceptance()


def _positive(value, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise InputError(f"{where}: expected a number > 0, got {value!r}")
    return float(value)


def read_acceptance(path) -> Acceptance:
    """Read and check an acceptance file (module docstring): a path, or the name of a bundled one
    (``example``: ``sbcal/acceptance/example.toml``, whose numbers are an example, not the standard's).

    Raises
    ------
    InputError
        One line naming the file and the key: missing file, malformed TOML, unknown key, both or neither
        excitation, a level or tolerance <= 0, a bad frequency range, no tolerance at all.
    """
    from ..core._io import resolve_bundled

    p = str(path)
    doc = resolve_bundled(path, "acceptance", "acceptance file", read_toml)
    for k in doc:
        if k not in _TOP:
            raise InputError(f"{p}: key '{k}': unknown (expected one of {', '.join(_TOP)})")
    exc = doc.get("excitation")
    if not isinstance(exc, dict):
        raise InputError(f"{p}: table [excitation]: missing (velocity_m_s or amplitude_mm_pp, and frequency_hz)")
    for k in exc:
        if k not in _EXCITATION:
            raise InputError(f"{p}: key 'excitation.{k}': unknown (expected one of {', '.join(_EXCITATION)})")
    given = [k for k in ("velocity_m_s", "amplitude_mm_pp") if k in exc]
    if len(given) != 1:
        raise InputError(f"{p}: table [excitation]: give exactly one of velocity_m_s, amplitude_mm_pp "
                         f"(got {', '.join(given) or 'neither'})")
    key = given[0]
    level = _positive(exc[key], f"{p}: key 'excitation.{key}'")
    rng = exc.get("frequency_hz")
    where = f"{p}: key 'excitation.frequency_hz'"
    if rng is None:
        raise InputError(f"{where}: missing (the range [lowest, highest] in Hz the criteria apply over)")
    if not isinstance(rng, list) or len(rng) != 2:
        raise InputError(f"{where}: expected [lowest, highest] in Hz, got {rng!r}")
    lo, hi = (_positive(v, where) for v in rng)
    if not lo < hi:
        raise InputError(f"{where}: expected lowest < highest, got {rng!r}")
    tol = doc.get("tolerance")
    if not isinstance(tol, dict) or not tol:
        raise InputError(f"{p}: table [tolerance]: missing or empty (one or more of {', '.join(TOLERANCES)})")
    for k in tol:
        if k not in TOLERANCES:
            hint = " (a top-level key goes before the first table)" if k in _TOP else ""
            raise InputError(f"{p}: key 'tolerance.{k}': unknown (expected one of {', '.join(TOLERANCES)}){hint}")
    tolerances = {k: _positive(v, f"{p}: key 'tolerance.{k}'") for k, v in tol.items()}
    same = doc.get("same_design", False)
    if not isinstance(same, bool):
        raise InputError(f"{p}: key 'same_design': expected true or false, got {same!r}")
    return Acceptance(mode="velocity" if key == "velocity_m_s" else "amplitude", level=level,
                      freq_range_hz=(lo, hi), tolerances=tolerances, same_design=same, source=p)
