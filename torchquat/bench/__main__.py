"""``python -m torchquat.bench``: the same program as ``torchquat bench``."""

import sys

from ..cli import main

if __name__ == "__main__":
    sys.exit(main(["bench", *sys.argv[1:]]))
