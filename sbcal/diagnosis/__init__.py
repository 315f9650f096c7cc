"""Missing physics: locate the misfit, name the physics left out, fit it, decide (``docs/diagnose.md``)."""

from ..core.lazy import lazy_exports


# Not here, named as their modules (once imported, a package attribute of that name is the
# submodule): diagnose; the top-level package exports them (sbcal.diagnose, ...).
_LAZY = {
    "DiagnoseConfig": ".diagnose", "curves_frame": ".diagnose",
}
__getattr__, __dir__ = lazy_exports(__name__, _LAZY)
__all__ = sorted(_LAZY)
