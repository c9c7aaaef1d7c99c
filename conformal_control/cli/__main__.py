"""``python -m conformal_control.cli``: the command line (as the ``conformal-control`` script)."""

import sys

from . import main

sys.exit(main())
