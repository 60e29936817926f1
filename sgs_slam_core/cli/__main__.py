"""``python -m sgs_slam_core.cli``."""

import sys

from sgs_slam_core.cli import main

sys.exit(main())
