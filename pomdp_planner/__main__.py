"""``python -m pomdp_planner`` runs the command line."""

import sys

from .cli import main

sys.exit(main())
