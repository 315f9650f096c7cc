"""Bench recordings: the contract's readers, test labels, cleaning and quality, the noise model
(``docs/data.md``); the bundled recordings (``bench.csv``) live beside them as package data."""

from ..core.lazy import lazy_exports


# Not here, named as their modules (once imported, a package attribute of that name is the
# submodule): clean_bench; the top-level package exports them (sbcal.clean_bench, ...).
_LAZY = {
    "load_bench": ".readers", "write_bench": ".bench", "curves_to_frame": ".bench",
    "noise_model": ".noise", "NoiseModel": ".noise", "quality_table": ".cleaning",
    "remove_outlier_runs": ".cleaning", "bench_summary": ".summary",
    "import_recordings": ".acquisition.importer", "load_channel_map": ".acquisition.channel_map",
}
__getattr__, __dir__ = lazy_exports(__name__, _LAZY)
__all__ = sorted(_LAZY)
