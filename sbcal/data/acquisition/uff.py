"""Universal File Format datasets 58 holding frequency response functions, read as ready lines:
frequency [Hz] and complex dynamic stiffness F/X [N/m] (``docs/import.md``, "UFF 58").

An FRF's numerator and denominator are named by its ordinate data characteristics (specific data
types: 8 displacement, 11 velocity, 12 acceleration, 9 and 13 force; an unknown or general one, 0 or 1,
is read from the axis units label). One of them must be force, the other the base motion; motion over force (receptance,
mobility, accelerance) is inverted, and velocity or acceleration is turned into displacement at each
line's frequency under the phase convention x(t) = Re(X e^{+iωt}) of modal testing and of sbcal:
F/X = F/V · iω, F/X = F/A · (−ω²). Units come from the axis labels when they name a known unit, else
from the file's units dataset 164 (its factors divide a value in the file's units to SI), else SI.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ...core.errors import InputError
from .units import parse_unit


__all__ = ["read_uff_lines"]

_FRF = 4  # function type of a frequency response function
_FREQUENCY = 18  # abscissa specific data type: frequency
_QUANTITY = {8: "displacement", 9: "force", 11: "velocity", 12: "acceleration", 13: "force"}
# (numerator, denominator) -> the FRF's name
_NAMES = {("displacement", "force"): "receptance", ("velocity", "force"): "mobility",
          ("acceleration", "force"): "accelerance", ("force", "displacement"): "dynamic stiffness",
          ("force", "velocity"): "mechanical impedance", ("force", "acceleration"): "apparent mass"}
_KEPT = ("id1", "id2", "id3", "id4", "id5", "load_case_id", "rsp_node", "rsp_dir", "ref_node", "ref_dir")


def read_uff_lines(path) -> list[tuple[np.ndarray, np.ndarray, dict]]:
    """The FRFs (function type 4) of a UFF file as dynamic stiffness lines.

    Parameters
    ----------
    path : str or path-like
        An ASCII or binary universal file (``.uff``, ``.unv``); datasets other than 58, and datasets 58
        that are not FRFs (coherence, time series, ...), are skipped.

    Returns
    -------
    list of (freq_hz, h, properties)
        Per FRF: ``freq_hz`` (n,) [Hz], the positive frequencies (a 0 Hz point holds no stiffness);
        ``h`` (n,) complex, F/X [N/m]; ``properties``: the dataset's ``id1``-``id5``, ``load_case_id``,
        response and reference node and direction, ``dataset`` (its position in the file, from 1),
        ``function`` (e.g. ``"accelerance"``), ``inverted`` (motion over force was inverted) and ``units``
        (where the unit factors came from).

    Raises
    ------
    InputError
        One line: pyuff missing, no FRF in the file, an abscissa that is not frequency, an FRF that is not
        force against motion, an axis label naming a unit of another quantity.
    """
    try:
        import pyuff
    except ImportError:
        raise InputError(f'reading {path} needs pyuff: pip install "sbcal[uff]"') from None
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: no such file")
    try:
        sets = pyuff.UFF(str(p)).read_sets()
    except Exception as e:  # a damaged file raises what the parser meets (ValueError, IndexError, ...)
        raise InputError(f"{p}: not a readable universal file ({e})") from None
    sets = [sets] if isinstance(sets, dict) else list(sets)
    units = next((s for s in sets if s.get("type") == 164), None)
    lines = []
    for k, s in enumerate(sets, 1):
        if s.get("type") == 58 and s.get("func_type") == _FRF:
            lines.append(_stiffness(s, units, f"{p}, dataset {k}", k))
    if not lines:
        raise InputError(f"{p}: no frequency response function (dataset 58, function type 4)")
    return lines


def _stiffness(s: dict, units: dict | None, where: str, k: int) -> tuple[np.ndarray, np.ndarray, dict]:
    if s.get("abscissa_spec_data_type", 0) not in (0, _FREQUENCY):
        raise InputError(f"{where}: the abscissa is not frequency (specific data type "
                         f"{s['abscissa_spec_data_type']})")
    num, num_factor, num_units = _axis(s, "ordinate", units, f"{where}: ordinate numerator")
    den, den_factor, den_units = _axis(s, "orddenom", units, f"{where}: ordinate denominator")
    name = _NAMES.get((num, den))
    if name is None:
        raise InputError(f"{where}: an FRF of {num} over {den}, not force against base motion")
    freq = np.asarray(s["x"], dtype=np.float64)
    h = np.asarray(s["data"], dtype=np.complex128) * (num_factor / den_factor)  # SI
    keep = freq > 0
    freq, h = freq[keep], h[keep]
    inverted = num != "force"
    if inverted:
        h = 1.0 / h
    motion = den if not inverted else num
    w = 2 * np.pi * freq
    h = h * {"displacement": 1.0, "velocity": 1j * w, "acceleration": -w ** 2}[motion]
    props = {key: s[key] for key in _KEPT if key in s}
    props.update(dataset=k, function=name, inverted=inverted,
                 units=num_units if num_units == den_units else f"{num_units} / {den_units}")
    return freq, h, props


def _axis(s: dict, prefix: str, units: dict | None, where: str) -> tuple[str, float, str]:
    """The quantity of an ordinate's numerator or denominator, its factor to SI, and where that came from."""
    code = s.get(f"{prefix}_spec_data_type", 0)
    label = str(s.get(f"{prefix}_axis_units_lab", "")).strip()
    try:
        from_label = parse_unit(label) if label and label.upper() != "NONE" else None
    except InputError:
        from_label = None
    if code in _QUANTITY:
        quantity = _QUANTITY[code]
    elif code in (0, 1) and from_label is not None:  # unknown or general: the label says
        quantity = from_label[0]
    else:
        raise InputError(f"{where}: neither force nor base motion (specific data type {code}, "
                         f"units label '{label}')")
    if from_label is not None and from_label[0] == quantity:
        return quantity, from_label[1], f"label '{label}'"
    if from_label is not None:
        raise InputError(f"{where}: units label '{label}' is not a unit of {quantity} (specific data type {code})")
    if units is None:
        return quantity, 1.0, "SI (no units dataset 164)"
    factor = float(units["force"] if quantity == "force" else units["length"])
    return quantity, 1.0 / factor, f"dataset 164 (units code {units.get('units_code')})"
