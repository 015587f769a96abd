"""Build this project's FMUs into ``build/fmus/<name>.fmu`` (or ``$FLEXARM_FMU_DIR``, or ``--out DIR``).

A thin entry point: the build tooling is the installable package :mod:`fmu_build`
(registry, C front end, packaging, documentation). ``python build_fmus.py --help``
lists the options; from Python, ``from fmu_build import build_all``.
"""

import sys

from fmu_build.cli import main

if __name__ == "__main__":
    sys.exit(main())
