"""``python -m flexarm.trajectory``: solve the slew and write the 1 ms file (see :mod:`.report`)."""

import sys

from .report import main

sys.exit(main())
