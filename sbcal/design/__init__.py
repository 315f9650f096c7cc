"""Using the calibrated cable: a new damper (``predict``), conductors and the span's energy balance
(``docs/predict.md``, ``docs/span.md``)."""
