"""``python -m acquisition.cli``: the ``sarbot`` command."""

import sys

from . import main

if __name__ == "__main__":
    sys.exit(main())
