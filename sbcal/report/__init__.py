"""The HTML report: one self-contained page per run store, with the lot's and the comparison's sections
(``docs/pipeline.md``)."""

from ..core.lazy import lazy_exports

_LAZY = {"build_report": ".build", "compare_section": ".compare", "lot_section": ".lot"}
__getattr__, __dir__ = lazy_exports(__name__, _LAZY)
__all__ = sorted(_LAZY)
