"""``python -m fmu_build``: see :mod:`fmu_build.cli`."""

import sys

from .cli import main

sys.exit(main())
