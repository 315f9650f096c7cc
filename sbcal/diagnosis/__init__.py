"""Missing physics: locate the misfit, name the physics left out, fit it, decide (``docs/diagnose.md``)."""
