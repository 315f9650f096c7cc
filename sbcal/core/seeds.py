"""Every job's random stream: spawned from ``--seed`` and keyed by what the job is.

A job (a test's posterior, a diagnosis's fit, a cable state's law, a damper's amplitude map) draws
its random numbers from ``job_seed(seed, stage, damper, test, ...)``: numpy's
:class:`~numpy.random.SeedSequence` of the user's seed with a *spawn key* made of the job's names.
That is the mechanism numpy's own ``spawn`` uses for independent child streams; here the child's key
is its name instead of its place in a list, so a test's draws do not depend on which other tests run,
in which order, or on which worker (``docs/calibration.md``, "Seeds"). Keys compose:
``job_seed(job_seed(s, "a"), "b")`` is ``job_seed(s, "a", "b")``.

A name becomes a spawn-key word through the first 4 bytes of its SHA-256 (Python's ``hash`` of a
string changes from process to process); two names share a word with probability 2**-32.
"""

from __future__ import annotations

import hashlib

import numpy as np


__all__ = ["job_seed", "seed_key"]


def _word(name) -> int:
    return int.from_bytes(hashlib.sha256(str(name).encode()).digest()[:4], "little")


def job_seed(seed, *key) -> np.random.SeedSequence:
    """The stream of the job named ``key`` under the user's ``seed``.

    Parameters
    ----------
    seed : int or numpy.random.SeedSequence
        The user's ``--seed`` (>= 0), or a job's stream to key further.
    *key : str
        What the job is, outermost first: e.g. ``("sample", "damper1", "0.5-0.5")``.

    Returns
    -------
    numpy.random.SeedSequence
    """
    words = tuple(_word(k) for k in key)
    if isinstance(seed, np.random.SeedSequence):
        return np.random.SeedSequence(seed.entropy, spawn_key=tuple(seed.spawn_key) + words)
    return np.random.SeedSequence(int(seed), spawn_key=words)


def seed_key(*key) -> str:
    """The job's key as stored beside its seed (``"sample/damper1/0.5-0.5"``)."""
    return "/".join(str(k) for k in key)
