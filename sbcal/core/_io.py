"""File input and output: TOML inputs read with one-line errors; atomic output (write to a
temporary file beside the target, then rename), so an interrupted command never leaves a
half-written output file behind.
"""

from __future__ import annotations

import math
import os
import tempfile
import tomllib
from contextlib import contextmanager
from pathlib import Path

from .errors import InputError


__all__ = ["read_toml", "name_and_description", "finite_number", "atomic_path", "write_json", "read_summary",
           "bundled_names", "resolve_bundled", "json_ready"]


def read_toml(path) -> dict:
    """A TOML file as a dict; a missing or unreadable file, text that is not UTF-8 and malformed
    TOML raise :class:`InputError` with one line naming the file."""
    p = Path(path)
    try:
        text = p.read_bytes()
    except FileNotFoundError:
        raise InputError(f"{p}: no such file") from None
    except OSError as e:
        raise InputError(f"{p}: cannot read: {e.strerror}") from None
    try:
        return tomllib.loads(text.decode("utf-8"))
    except UnicodeDecodeError as e:
        raise InputError(f"{p}: not UTF-8 text (byte {e.start})") from None
    except tomllib.TOMLDecodeError as e:
        raise InputError(f"{p}: invalid TOML: {e}") from None


def name_and_description(doc: dict, path: str) -> tuple[str, str]:
    """The ``name`` (required, a non-empty string) and ``description`` (default "") of a parsed
    description file; a missing or malformed one raises :class:`InputError` naming ``path`` and the key."""
    name = doc.get("name")
    if name is None:
        raise InputError(f"{path}: key 'name': missing")
    if not isinstance(name, str) or not name.strip():
        raise InputError(f"{path}: key 'name': expected a non-empty string, got {name!r}")
    description = doc.get("description", "")
    if not isinstance(description, str):
        raise InputError(f"{path}: key 'description': expected a string, got {type(description).__name__}")
    return name, description


def finite_number(text: str, what: str) -> float:
    """``text`` as a finite float (a ``--set`` value on the command line, an effect's value of the virtual bench).

    Parameters
    ----------
    text : str
    what : str
        Where it was given, the start of the error, e.g. ``"effect 'sensor_delay=x'"``.

    Raises
    ------
    InputError
        One line: ``text`` is not a number, or not finite.
    """
    try:
        x = float(text)
    except ValueError:
        raise InputError(f"{what}: {text!r} is not a number") from None
    if not math.isfinite(x):
        raise InputError(f"{what}: value is not finite")
    return x


@contextmanager
def atomic_path(path, suffix: str = ""):
    """Yield a temporary path in the target's directory; rename it onto ``path`` on success.

    The parent directory is created. On any exception the temporary file is removed and
    ``path`` is left as it was.
    """
    target = Path(path)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=suffix or ".tmp", dir=target.parent)
    except OSError as e:
        raise InputError(f"{target}: cannot write: {e.strerror}") from None
    os.close(fd)
    try:
        yield Path(tmp)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; give the usual permissions
        os.replace(tmp, target)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def write_json(path, doc, **dumps) -> None:
    """Write ``doc`` as JSON (``json.dumps(doc, **dumps)`` and a newline) to ``path``, atomically."""
    import json

    with atomic_path(path, ".json") as tmp:
        tmp.write_text(json.dumps(doc, **dumps) + "\n", encoding="utf-8")


def json_ready(x):
    """NaN and inf as None, recursively through dicts, lists and tuples (JSON without NaN)."""
    if isinstance(x, dict):
        return {k: json_ready(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [json_ready(v) for v in x]
    if isinstance(x, float) or getattr(getattr(x, "dtype", None), "kind", "") == "f" and getattr(x, "ndim", 1) == 0:
        return float(x) if math.isfinite(x) else None  # a Python or numpy float scalar
    return x


def read_summary(directory, keys, what: str, writer: str) -> dict:
    """The ``summary.json`` of a stored result (``what``, e.g. "span study", written by ``writer``),
    checked for its main ``keys``; one-line InputError when missing, not JSON or not such a result."""
    import json

    p = Path(directory) / "summary.json"
    if not p.is_file():
        raise InputError(f"{directory}: no stored {what} (summary.json missing)")
    try:
        doc = json.loads(p.read_text())
    except json.JSONDecodeError as e:
        raise InputError(f"{p}: not valid JSON ({e.msg}, line {e.lineno})") from None
    if not isinstance(doc, dict):
        raise InputError(f"{p}: expected a JSON object (not a {what} written by {writer})")
    for key in keys:
        if key not in doc:
            raise InputError(f"{p}: key '{key}': missing (not a {what} written by {writer})")
    return doc


def bundled_names(folder: str) -> list[str]:
    """Names of the TOML descriptions shipped with sbcal in ``sbcal/<folder>/`` (``models``, ``conductors``)."""
    from importlib import resources

    root = resources.files("sbcal") / folder
    return sorted(f.name[:-5] for f in root.iterdir() if f.name.endswith(".toml"))


def resolve_bundled(name_or_path, folder: str, kind: str, load):
    """``load`` of a bundled description by name (``damper1``) or of a description file by path.

    Parameters
    ----------
    name_or_path : str or path-like
    folder : str
        The package-data folder of the bundled descriptions.
    kind : str
        What is described (``damper``), for the error.
    load : callable
        Reads one TOML file.
    """
    from importlib import resources

    s = str(name_or_path)
    if not s.endswith(".toml") and "/" not in s and s in bundled_names(folder):
        with resources.as_file(resources.files("sbcal") / folder / f"{s}.toml") as f:
            return load(f)
    if not Path(s).exists() and "/" not in s and not s.endswith(".toml"):
        raise InputError(f"{kind} '{s}': neither a bundled {kind} ({', '.join(bundled_names(folder))}) nor a file")
    return load(s)
