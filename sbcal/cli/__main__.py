"""``python -m sbcal.cli``: the same as the ``sbcal`` command."""

from .app import main


raise SystemExit(main())
