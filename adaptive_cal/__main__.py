"""``python -m adaptive_cal``: the same as the ``adaptive-cal`` command."""
import sys

from adaptive_cal.cli import main

sys.exit(main())
