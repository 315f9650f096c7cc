"""Prior boxes (``priors/*.toml``, schema in ``docs/calibration.md``) and the sampled coordinates.

A :class:`Prior` is the product of independent uniform or log-uniform boxes over the parameters
of one named set (``theta1`` ...) plus the likelihood's model-error scales, reached by name. The sampler works in
coordinates ``z`` where every box is uniform: ``z = x`` for a uniform parameter and
``z = log(x)`` for a log-uniform one, so the log-prior is 0 inside the box and ``-inf`` outside. A
:class:`Shear` may move a coordinate by a function of the others (a triangular map: the log-Jacobian, where not 0,
is in :meth:`Prior.log_prob`): the cable fit's (:mod:`sbcal.inference.cable_coords`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from importlib import resources
from pathlib import Path

import numpy as np

from ..core._io import read_toml
from ..core.errors import InputError
from ..model.damper import Damper
from ..model.fem import PARAMETER_NAMES


__all__ = ["Prior", "Shear", "canonical_order", "load_prior", "parameter_sets", "extension_prior", "composed_prior",
           "cable_prior", "default_path"]

_DISTS = ("uniform", "loguniform")
_MODEL_ERROR = ("sigma_mag", "sigma_phase")


def canonical_order(names) -> tuple:
    """Parameter names in sbcal's canonical order, whatever order a prior file lists them in.

    The forward model's vocabulary (:data:`sbcal.model.fem.PARAMETER_NAMES`) first in its own order, then
    any other name (extension and law parameters) alphabetically, then the model-error scales. The
    sampler's coordinates follow this order, so permuting a set in a prior file changes nothing.
    """
    rank = {n: i for i, n in enumerate(PARAMETER_NAMES)}
    names = list(dict.fromkeys(names))
    return tuple(sorted(names, key=lambda n: (n in _MODEL_ERROR, _MODEL_ERROR.index(n) if n in _MODEL_ERROR else 0,
                                              n not in rank, rank.get(n, 0), n)))


@dataclass(frozen=True)
class Shear:
    """One coordinate moved by a function ``o`` of the others.

    Two kinds: ``"log"`` moves a log-uniform coordinate, ``z = ln x + o`` (Jacobian 1, the density in the new
    coordinates is the same); ``"scale"`` scales a uniform one whose box starts at 0 or above, ``z = x e^o``
    (Jacobian ``e^-o``: the density in ``z`` carries ``-o``, :meth:`Prior.log_prob`). ``o`` reads the other
    parameters only, so the map is triangular and its inverse explicit.

    Attributes
    ----------
    name : str
        The moved parameter.
    offset : callable
        Picklable; natural values of the other parameters by name, each ``(n,)`` -> ``o`` ``(n,)``; NaN where
        they are outside the model's domain (the point is then outside the prior). It is given only the
        parameters no later shear of the same prior moves (:attr:`Prior.shears`).
    lower, upper : float
        ``o`` is clipped to ``[lower, upper]``; the sampled box of ``name`` is widened by them.
    kind : str
        ``"log"`` or ``"scale"``.
    """

    name: str
    offset: object
    lower: float = -12.0
    upper: float = 0.0
    kind: str = "log"


@dataclass(frozen=True)
class Prior:
    """Independent boxes over named parameters, in natural units.

    Attributes
    ----------
    paramset : str
        Name of the set (e.g. ``"theta1"``).
    names : tuple of str
        The sampled parameters in canonical order (:func:`canonical_order`): model parameters first,
        then ``sigma_mag``, ``sigma_phase`` where the set has them.
    log_scale : ndarray of bool, shape (ndim,)
        True where the box is log-uniform (sampled as ``log x``).
    lower, upper : ndarray, shape (ndim,)
        Box bounds in natural units.
    shears : tuple of Shear
        The coordinates moved (:meth:`sheared`), in order: each shear's offset reads the unmoved parameters and
        those of the shears before it, so the natural values are recovered in this order. :attr:`z_lower`,
        :attr:`z_upper` are then the box of the moved coordinates, and :meth:`log_prob` the box of ``x`` plus the
        ``"scale"`` shears' log-Jacobian.
    redrawn : tuple of str
        Parameters the data leave prior-dominated over part of their box (:meth:`redrawing`): besides its moves,
        the engine redraws each from its whole box now and then, the others held
        (:class:`sbcal.inference.sampler.SamplerConfig`'s ``redraw_every``).

    Construct with :meth:`from_boxes` (any order of names); code outside this class reaches a
    parameter by its name (:meth:`params`, :meth:`z_of`), never by its position.
    """

    paramset: str
    names: tuple
    log_scale: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    shears: tuple = ()
    redrawn: tuple = ()

    @classmethod
    def from_boxes(cls, paramset: str, boxes: dict) -> "Prior":
        """``boxes``: name -> ``(log_scale, lower, upper)``, in any order."""
        names = canonical_order(boxes)
        rows = [boxes[n] for n in names]
        return cls(paramset=paramset, names=names, log_scale=np.array([bool(r[0]) for r in rows]),
                   lower=np.array([float(r[1]) for r in rows]), upper=np.array([float(r[2]) for r in rows]))

    @property
    def ndim(self) -> int:
        return len(self.names)

    @property
    def model_names(self) -> tuple:
        """The forward-model parameters (without the model-error scales)."""
        return tuple(n for n in self.names if n not in _MODEL_ERROR)

    def __post_init__(self):
        if tuple(self.names) != canonical_order(self.names):
            raise ValueError(f"Prior names must be in canonical order (use Prior.from_boxes): {self.names}")
        # the box in sampled coordinates, computed once: log_prob runs on every sampler step
        for name, bound in (("z_lower", self.lower), ("z_upper", self.upper)):
            z = np.where(self.log_scale, np.log(np.where(self.log_scale, bound, 1.0)), bound)
            object.__setattr__(self, name, z)
        object.__setattr__(self, "_box", (self.z_lower, self.z_upper))  # of the unmoved coordinates
        unknown = [n for n in self.redrawn if n not in self.names]
        if unknown or len(set(self.redrawn)) < len(self.redrawn):
            raise ValueError(f"redrawn parameters must be distinct parameters of the prior: {self.redrawn}")
        moved = [s.name for s in self.shears]
        if len(set(moved)) < len(moved):
            raise ValueError(f"each coordinate is moved at most once: {moved}")
        lo, hi = self.z_lower.copy(), self.z_upper.copy()
        for s in self.shears:
            i = self.names.index(s.name)
            if s.kind == "log":
                if not self.log_scale[i]:
                    raise ValueError(f"a log shear moves a log-uniform coordinate; {s.name} is uniform")
                lo[i] += s.lower
                hi[i] += s.upper
            elif s.kind == "scale":
                if self.log_scale[i] or self.lower[i] < 0:
                    raise ValueError(f"a scale shear moves a uniform coordinate on [>= 0, ...]; {s.name} is not")
                lo[i] *= math.exp(s.lower)
                hi[i] *= math.exp(s.upper)
            else:
                raise ValueError(f"shear kind {s.kind!r}: expected 'log' or 'scale'")
        object.__setattr__(self, "z_lower", lo)
        object.__setattr__(self, "z_upper", hi)

    def sheared(self, *shears: Shear) -> "Prior":
        """The same boxes sampled in the coordinates ``shears`` move (after this prior's own)."""
        return replace(self, shears=self.shears + tuple(shears))

    def redrawing(self, *names: str) -> "Prior":
        """The same prior with ``names`` redrawn from their boxes by the engine (:attr:`redrawn`)."""
        return replace(self, redrawn=self.redrawn + tuple(names))

    def _offset(self, k: int, x) -> tuple[int, np.ndarray]:
        """Shear ``k``'s ``(column, o)`` at natural values ``x`` (n, ndim), ``o`` clipped; its offset is given the
        parameters that no shear from ``k`` on moves."""
        s = self.shears[k]
        later = {t.name for t in self.shears[k:]}
        with np.errstate(invalid="ignore"):
            o = s.offset({n: x[:, j] for j, n in enumerate(self.names) if n not in later})
        return self.names.index(s.name), np.clip(np.broadcast_to(o, x.shape[:1]), s.lower, s.upper)

    def _move(self, z, x) -> np.ndarray:
        """Unmoved coordinates ``z`` (n, ndim) of natural values ``x`` -> the sampled ones (in place)."""
        for k, s in enumerate(self.shears):
            i, o = self._offset(k, x)
            if s.kind == "log":
                z[:, i] += o
            else:
                z[:, i] *= np.exp(o)
        return z

    def _unmoved(self, z) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Sampled coordinates ``z`` (n, ndim) -> ``(u, x, log_jacobian)``: the unmoved coordinates, natural
        values and the ``"scale"`` shears' ``-o`` summed (n,); the shears undone in order, each offset reading the
        columns recovered before it."""
        u = np.array(z, dtype=float, ndmin=2)
        x = np.where(self.log_scale, np.exp(u), u)
        jac = np.zeros(u.shape[0])
        for k, s in enumerate(self.shears):
            i, o = self._offset(k, x)
            if s.kind == "log":
                u[:, i] -= o
                x[:, i] = np.exp(u[:, i])
            else:
                u[:, i] *= np.exp(-o)
                x[:, i] = u[:, i]
                jac -= o
        return u, x, jac

    def box(self, name: str) -> tuple[bool, float, float]:
        """``(log_scale, lower, upper)`` of one parameter."""
        i = self.names.index(name)
        return bool(self.log_scale[i]), float(self.lower[i]), float(self.upper[i])

    def to_natural(self, z) -> np.ndarray:
        """Sampled coordinates ``(n, ndim)`` -> natural units ``(n, ndim)``."""
        z = np.atleast_2d(z)
        if not self.shears:
            return np.where(self.log_scale, np.exp(z), z)
        return self._unmoved(z)[1]

    def to_z(self, x) -> np.ndarray:
        """Natural units ``(n, ndim)`` -> sampled coordinates."""
        x = np.atleast_2d(np.asarray(x, dtype=float))
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.where(self.log_scale, np.log(x), x)
        return self._move(z, x)

    def params(self, z) -> dict:
        """Sampled coordinates ``(n, ndim)`` -> ``{name: natural values (n,)}``."""
        x = self.to_natural(z)
        return {n: x[:, i] for i, n in enumerate(self.names)}

    def z_of(self, params: dict) -> np.ndarray:
        """``{name: natural value(s)}`` (every parameter of the prior) -> sampled coordinates ``(n, ndim)``."""
        missing = [n for n in self.names if n not in params]
        if missing:
            raise KeyError(f"no value for {', '.join(missing)}")
        cols = np.broadcast_arrays(*(np.atleast_1d(np.asarray(params[n], float)) for n in self.names))
        return self.to_z(np.stack(cols, axis=1))

    def log_prob(self, z) -> np.ndarray:
        """Log-density in ``z``: shape ``(n,)``, ``-inf`` outside the box of ``x``; inside 0, plus ``-o`` of each
        ``"scale"`` shear (its log-Jacobian)."""
        return self._density(z)[0]

    def _density(self, z) -> tuple[np.ndarray, np.ndarray]:
        """``(log_prob, x)`` at sampled coordinates ``z`` (n, ndim), the shears undone once."""
        u, x, jac = self._unmoved(z)
        lo, hi = self._box
        with np.errstate(invalid="ignore"):
            inside = np.all((u >= lo) & (u <= hi), axis=1)
        return np.where(inside, jac, -np.inf), x

    def log_posterior(self, z, log_likelihood) -> np.ndarray:
        """The engine's target: :meth:`log_prob` plus ``log_likelihood(params) -> (n,)`` (natural values by name)
        at the sets inside the box; ``(n,)``, ``-inf`` outside it and where the likelihood is not finite (a NaN
        would stop the sampler)."""
        out, x = self._density(z)
        ok = np.isfinite(out)
        if ok.any():
            with np.errstate(all="ignore"):
                lp = np.asarray(log_likelihood({n: x[ok, i] for i, n in enumerate(self.names)}), dtype=float)
            out[ok] += np.where(np.isfinite(lp), lp, -np.inf)
        return out

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """``n`` draws in ``z``, shape ``(n, ndim)`` (uniform in the boxes of ``x``; with shears, rows of NaN where
        an offset is undefined)."""
        lo, hi = self._box
        z = rng.uniform(lo, hi, size=(n, self.ndim))
        if self.shears:
            z = self._move(z, np.where(self.log_scale, np.exp(z), z))
        return z

    def middle(self) -> dict:
        """Natural values by name at the middle of every box (in its own scale: the geometric mean of a
        log-uniform one)."""
        lo, hi = self._box
        mid = (lo + hi) / 2
        return {n: float(v) for n, v in zip(self.names, np.where(self.log_scale, np.exp(mid), mid))}

    def as_dict(self) -> dict:
        """JSON-friendly description (stored with every run)."""
        out = {"paramset": self.paramset, "parameters": {
            n: {"dist": "loguniform" if s else "uniform", "lower": float(lo), "upper": float(hi)}
            for n, s, lo, hi in zip(self.names, self.log_scale, self.lower, self.upper)}}
        if self.shears:
            out["sampled_as"] = [{"parameter": s.name, "kind": s.kind, "offset": repr(s.offset)} for s in self.shears]
        if self.redrawn:
            out["redrawn"] = list(self.redrawn)
        return out


def default_path(name="default.toml"):
    """The bundled prior file ``name`` (a resource in ``sbcal/priors``)."""
    return resources.files("sbcal") / "priors" / name


def _read(path, bundled="default.toml") -> tuple[dict, str]:
    if path is None:
        with resources.as_file(default_path(bundled)) as p:
            return read_toml(p), f"priors/{bundled}"
    return read_toml(path), str(Path(path))


def parameter_sets(path=None) -> dict:
    """Named parameter sets of a prior file: ``{"theta1": ["beta", "a1", "a2", "EJ"], ...}``."""
    doc, src = _read(path)
    sets = doc.get("sets")
    if not isinstance(sets, dict) or not sets:
        raise InputError(f"{src}: table '[sets]': missing or empty")
    return {k: list(v) for k, v in sets.items()}


def _bounds(src: str, key: str, spec: dict, name: str, damper: Damper) -> tuple[bool, float, float]:
    if not isinstance(spec, dict):
        raise InputError(f"{src}: key '{key}': expected a table")
    dist = spec.get("dist")
    if dist not in _DISTS:
        raise InputError(f"{src}: key '{key}.dist': expected one of {', '.join(_DISTS)}, got {dist!r}")
    ways = [w for w in ("lower", "relative", "fraction_of_ej_static") if w in spec]
    if len(ways) != 1:
        raise InputError(f"{src}: key '{key}': give exactly one of lower/upper, relative, fraction_of_ej_static")

    def num(k, v):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise InputError(f"{src}: key '{key}.{k}': expected a finite number, got {v!r}")
        return float(v)

    if ways[0] == "lower":
        if "upper" not in spec:
            raise InputError(f"{src}: key '{key}.upper': missing")
        lo, hi = num("lower", spec["lower"]), num("upper", spec["upper"])
    elif ways[0] == "relative":
        r = num("relative", spec["relative"])
        if not 0 <= r < 1:
            raise InputError(f"{src}: key '{key}.relative': must be in [0, 1), got {r}")
        nominal = getattr(damper, name)
        lo, hi = sorted((nominal * (1 - r), nominal * (1 + r)))
    else:
        f = spec["fraction_of_ej_static"]
        if not isinstance(f, list) or len(f) != 2:
            raise InputError(f"{src}: key '{key}.fraction_of_ej_static': expected [lo, hi]")
        lo, hi = (num("fraction_of_ej_static", v) * damper.ej_static for v in f)
    if not lo < hi:
        raise InputError(f"{src}: key '{key}': lower {lo:g} must be < upper {hi:g}")
    if dist == "loguniform" and lo <= 0:
        raise InputError(f"{src}: key '{key}': a log-uniform box needs lower > 0, got {lo:g}")
    return dist == "loguniform", lo, hi


def load_prior(paramset: str, damper: Damper, path=None) -> Prior:
    """The prior of one named parameter set for one damper.

    Parameters
    ----------
    paramset : str
        A name from the file's ``[sets]`` (``theta1``, ``theta2``, ``theta3``, ``poly2``..``poly4``).
    damper : Damper
        Supplies nominal values (relative boxes) and ``ej_static``.
    path : path-like, optional
        A prior file; default the bundled ``priors/default.toml``.
    """
    doc, src = _read(path)
    sets = parameter_sets(path)
    if paramset not in sets:
        raise InputError(f"{src}: parameter set {paramset!r} not in [sets] ({', '.join(sets)})")
    names = list(sets[paramset])
    for n in names:
        if n not in PARAMETER_NAMES:
            raise InputError(f"{src}: key 'sets.{paramset}': unknown parameter {n!r}")
    table = doc.get("parameters", {})
    errors = doc.get("model_error", {})
    if len(set(names)) != len(names):
        raise InputError(f"{src}: key 'sets.{paramset}': a parameter is listed twice")
    boxes = {}
    for n in names:
        if n not in table:
            raise InputError(f"{src}: key 'parameters.{n}': missing (used by set {paramset!r})")
        boxes[n] = _bounds(src, f"parameters.{n}", table[n], n, damper)
    for n in _MODEL_ERROR:
        if n not in errors:
            raise InputError(f"{src}: key 'model_error.{n}': missing")
        boxes[n] = _bounds(src, f"model_error.{n}", errors[n], n, damper)
    return Prior.from_boxes(paramset, boxes)


def extension_prior(effect: str, damper: Damper, path=None, base_path=None, *, bundled: str = "extensions.toml") -> Prior:
    """The prior of a physics extension of ``sbcal diagnose`` (or of its ``baseline``).

    The extension keeps the ``base`` parameters of the default prior file (their boxes) and adds
    its own; there are no model-error scales: the diagnosis's likelihood is the noise model's.

    Parameters
    ----------
    effect : str
        ``"baseline"`` or a catalogue id (``priors/extensions.toml``).
    damper : Damper
    path : path-like, optional
        An extensions file; default the bundled ``priors/extensions.toml`` (``bundled``).
    base_path : path-like, optional
        The prior file of the ``base`` parameters; default ``priors/default.toml``.
    bundled : str
        The bundled file read when ``path`` is None (:func:`cable_prior` reads ``cable.toml``).
    """
    doc, src = _read(path, bundled)
    spec = doc.get(effect)
    if not isinstance(spec, dict):
        raise InputError(f"{src}: table '[{effect}]': missing")
    base = spec.get("base", [])
    if not isinstance(base, list) or not all(isinstance(n, str) for n in base):
        raise InputError(f"{src}: key '{effect}.base': expected a list of parameter names")
    base_doc, base_src = _read(base_path)
    table = base_doc.get("parameters", {})
    boxes = {}
    for n in base:
        if n not in PARAMETER_NAMES or n not in table:
            raise InputError(f"{src}: key '{effect}.base': {n!r} is not a parameter of {base_src}")
        boxes[n] = _bounds(base_src, f"parameters.{n}", table[n], n, damper)
    for n, box in spec.get("parameters", {}).items():
        if n in boxes:
            raise InputError(f"{src}: key '{effect}.parameters.{n}': also a base parameter")
        boxes[n] = _bounds(src, f"{effect}.parameters.{n}", box, n, damper)
    return Prior.from_boxes(effect, boxes)


def composed_prior(primary: str, secondary, damper: Damper, *, base_path=None) -> Prior:
    """The prior of a catalogue effect (or ``"baseline"``) with ``secondary`` effects on top: the
    primary's boxes and each secondary's own parameters; named ``primary+secondary...``."""
    prior = extension_prior(primary, damper, base_path=base_path)
    boxes = {n: prior.box(n) for n in prior.names}
    for e in secondary:
        ext = extension_prior(e, damper, base_path=base_path)
        boxes.update({n: ext.box(n) for n in ext.names if n not in boxes})
    return Prior.from_boxes("+".join((primary,) + tuple(secondary)), boxes)


def cable_prior(law: str, damper: Damper, path=None, base_path=None) -> Prior:
    """The prior of a cable law family: the ``base`` geometry of the default prior file and the cable's
    own parameters (``[cable]`` of ``priors/cable.toml``), then the law's parameters in the boxes the law
    states (:attr:`sbcal.model.laws.base.LawParameter.prior`) unless the file's ``[LAW.parameters.NAME]``
    overrides one. A zoned family (``iwan5_zoned``, :mod:`sbcal.model.laws.zones`) is its middle's prior
    plus the table ``[zones]`` (the zones' lengths and ratios)."""
    from ..model.laws import LAWS, ZONED_SUFFIX, law_for

    law_for(law)  # one line for an unknown law
    family = law[:-len(ZONED_SUFFIX)] if law.endswith(ZONED_SUFFIX) else law
    cable = extension_prior("cable", damper, path, base_path, bundled="cable.toml")
    boxes = {n: cable.box(n) for n in cable.names}
    doc, src = _read(path, "cable.toml")
    table = doc.get(family, {})
    overrides = table.get("parameters", {}) if isinstance(table, dict) else None
    if not isinstance(overrides, dict):
        raise InputError(f"{src}: key '{family}.parameters': expected a table")
    own = LAWS[family].parameters
    unknown = sorted(set(overrides) - {p.name for p in own})
    if unknown:
        raise InputError(f"{src}: key '{family}.parameters.{unknown[0]}': not a parameter of the {family} law "
                         f"({', '.join(p.name for p in own)})")
    for p in own:
        if p.name in overrides:
            boxes[p.name] = _bounds(src, f"{family}.parameters.{p.name}", overrides[p.name], p.name, damper)
        elif p.prior:
            dist, lower, upper, *relative = p.prior
            spec = ({"dist": dist, "fraction_of_ej_static": [lower, upper]} if relative
                    else {"dist": dist, "lower": lower, "upper": upper})
            boxes[p.name] = _bounds(f"the {family} law", f"{p.name}.prior", spec, p.name, damper)
        else:
            raise InputError(f"{src}: the {family} law's parameter {p.name!r} has no prior box; give "
                             f"[{family}.parameters.{p.name}]")
    if law != family:
        zones = extension_prior("zones", damper, path, base_path, bundled="cable.toml")
        boxes.update({n: zones.box(n) for n in zones.names if n not in boxes})
    return Prior.from_boxes(law, boxes)
