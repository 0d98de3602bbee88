"""``python -m magcal`` runs the magcal command."""

import sys

from magcal.cli import main

sys.exit(main())
