"""``python -m pcprep`` runs the command line."""

import sys

from pcprep.meshlab_bridge.cli import main

sys.exit(main())
