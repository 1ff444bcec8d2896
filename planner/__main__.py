"""`python -m planner` is the same as the `regrasp` command."""

from planner.cli import main

raise SystemExit(main())
