"""``python -m conformal_control.cli``: the command line (as the ``conformal-control`` script)."""

import sys

from . import main

if __name__ == "__main__":  # imported (e.g. by testing.discover walking the package): nothing runs
    sys.exit(main())
