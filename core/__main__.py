"""``python -m core``: the core's command line (see :mod:`core.cli`)."""

from .cli import main

raise SystemExit(main())
