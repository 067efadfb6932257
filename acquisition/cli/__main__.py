"""``python -m acquisition.cli``: the ``sarbot`` command."""

import sys

from . import end_process, main

if __name__ == "__main__":
    sys.exit(end_process(main()))
