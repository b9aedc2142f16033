"""``python -m torchquat.crosscheck``: the same as ``torchquat crosscheck``."""

import sys

from . import main

if __name__ == "__main__":
    sys.exit(main())
