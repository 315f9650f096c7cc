"""The cleaned bench: a bench file with each test's outlier runs decided once.

The pipeline's clean stage decides which runs of every test are kept (:func:`sbcal.data.cleaning.remove_outlier_runs`)
and stores the decision in the run store (``data.json``); every later stage — sampling, diagnosis, cable-law
fits, the joint amplitude map — reads its runs from a :class:`CleanBench` made from that stored decision,
so no stage cleans again, and all of them see the same runs.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..core.errors import InputError
from .bench import BenchData, TestData
from .cleaning import DEFAULT_Z_THRESHOLD, check_threshold, remove_outlier_runs


__all__ = ["CleanBench", "clean_bench"]


@dataclass(frozen=True, eq=False)
class CleanBench:
    """Bench recordings and, per test, the runs set aside as outliers (picklable: it travels to workers).

    Attributes
    ----------
    bench : BenchData
        The recordings as read (every run).
    removed : dict
        ``{(damper, test): tuple of run ids}``: the runs the cleaning set aside, for every test of
        :attr:`dampers` (``()`` when none).
    z_threshold : float
        The outlier-run threshold the decision was made with.
    """

    bench: BenchData
    removed: dict
    z_threshold: float = DEFAULT_Z_THRESHOLD

    @property
    def source(self) -> str:
        return self.bench.source

    @property
    def frame(self):
        return self.bench.frame

    def dampers(self) -> list[str]:
        """The cleaned dampers, sorted."""
        return sorted({d for d, _ in self.removed})

    def tests(self, damper: str) -> list[str]:
        """Test labels of ``damper`` in :meth:`BenchData.tests` order."""
        if damper not in self.dampers():
            self.bench.tests(damper)  # an unknown damper: the bench's own message
            raise InputError(f"{self.source}: damper {damper!r} was not cleaned (cleaned: {', '.join(self.dampers())})")
        return [t for t in self.bench.tests(damper) if (damper, t) in self.removed]

    def test(self, damper: str, test: str) -> TestData:
        """Every run of a test, as recorded (:meth:`BenchData.test`)."""
        return self.bench.test(damper, test)

    def removed_runs(self, damper: str, test: str) -> tuple[int, ...]:
        """Ids of the test's runs set aside, ascending."""
        try:
            return self.removed[damper, test]
        except KeyError:
            self.bench.test(damper, test)  # an unknown label: the bench's own message
            raise InputError(f"{self.source}: damper {damper!r} test {test!r} was not cleaned") from None

    def kept(self, damper: str, test: str) -> TestData:
        """The test's kept runs: what the likelihoods of every stage are made of."""
        removed = self.removed_runs(damper, test)
        data = self.bench.test(damper, test)
        return data.select_runs([r for r in data.runs if r not in removed]) if removed else data

    @classmethod
    def from_stored(cls, bench: BenchData, tests: dict, *, z_threshold: float,
                    source: str = "data.json") -> "CleanBench":
        """A cleaned bench from stored decisions ``{damper: {test: {"removed_runs": [...], ...}}}``
        (the ``tests`` of the clean stage's ``data.json``); ``source`` names the file in messages."""
        removed = {}
        for damper, per_test in tests.items():
            for test, doc in per_test.items():
                runs = doc.get("removed_runs") if isinstance(doc, dict) else None
                if not isinstance(runs, list) or not all(isinstance(r, int) for r in runs):
                    raise InputError(f"{source}: key 'tests.{test}.removed_runs': expected a list of run ids")
                missing = set(runs) - set(bench.test(damper, test).runs.tolist())
                if missing:
                    raise InputError(f"{source}: key 'tests.{test}.removed_runs': run {min(missing)} is not a run of "
                                     f"{damper} {test} in {bench.source}")
                removed[damper, test] = tuple(sorted(runs))
        return cls(bench, removed, check_threshold(z_threshold))


def clean_bench(bench: BenchData, z_threshold: float = DEFAULT_Z_THRESHOLD, *, dampers=None) -> CleanBench:
    """Decide every test's outlier runs (:func:`sbcal.data.cleaning.remove_outlier_runs`) for ``dampers``
    (default: all of the file's). The pipeline stores this decision and later stages read it back
    (:meth:`CleanBench.from_stored`); this function is for a bench used outside a run store."""
    z = check_threshold(z_threshold)
    if isinstance(bench, CleanBench):
        raise TypeError("clean_bench: the bench is already cleaned")
    names = bench.dampers() if dampers is None else list(dampers)
    removed = {(d, t): remove_outlier_runs(bench.test(d, t), z).removed_runs for d in names for t in bench.tests(d)}
    return CleanBench(bench, removed, z)
