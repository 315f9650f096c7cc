"""The ground floor: errors, atomic file writing, progress bars, worker processes, random streams, figures.

Everything else in sbcal may import from here; nothing here imports from the rest."""
