"""``python -m clis_app.cli``: the ``clis`` command."""

from clis_app.cli import main

raise SystemExit(main())
