"""``python -m torchquat.bench``: the same as ``torchquat bench``."""

from . import main

raise SystemExit(main())
