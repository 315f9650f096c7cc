"""The physics: damper descriptions, the 6-DOF finite-element model, the hysteresis laws of the cable,
the distributed cable model and the catalogue of physics extensions (``docs/model.md``, ``docs/cable.md``)."""
