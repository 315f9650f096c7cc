"""Atomic file output: write to a temporary file beside the target, then rename.

An interrupted command never leaves a half-written output file behind.
"""

from __future__ import annotations

import os
import tempfile
from contextlib import contextmanager
from pathlib import Path

from .errors import InputError

__all__ = ["atomic_path", "write_json"]


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
