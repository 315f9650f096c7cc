"""Bench recordings: the contract's readers, test labels, cleaning and quality, the noise model
(``docs/data.md``); the bundled recordings (``bench.csv``) live beside them as package data."""
