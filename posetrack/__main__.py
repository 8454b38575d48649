"""``python -m posetrack``: the command line (same as the ``posetrack`` script)."""

import sys

from .app import main

sys.exit(main())
