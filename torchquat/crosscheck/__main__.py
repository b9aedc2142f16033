"""``python -m torchquat.crosscheck``: the same program as ``torchquat crosscheck``."""

import sys

from ..cli import main

if __name__ == "__main__":
    sys.exit(main(["crosscheck", *sys.argv[1:]]))
