"""The virtual shaker bench: recordings made from physics richer than the fitted models
(``docs/virtual_bench.md``)."""
