"""``python -m torchquat``: the same program as the ``torchquat`` command."""

import sys

from .cli import main

if __name__ == "__main__":
    sys.exit(main())
