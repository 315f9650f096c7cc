"""The virtual shaker bench: recordings made from physics richer than the fitted models
(``docs/virtual_bench.md``)."""

from ..core.lazy import lazy_exports

_LAZY = {
    "BenchConfig": ".virtual_bench", "record": ".virtual_bench", "SlipLaw": ".effects",
    "parse_effect": ".effects", "LotConfig": ".virtual_lot", "record_lot": ".virtual_lot",
    "record_raw": ".raw_bench",
}
__getattr__, __dir__ = lazy_exports(__name__, _LAZY)
__all__ = sorted(_LAZY)
