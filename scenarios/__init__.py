"""The scenarios, their runs and what reports them (``python -m scenarios``): one sub-package per concern, layered
(docs/architecture.md, "`scenarios/` by concern")."""

import sys
from pathlib import Path


def _unshadow_packages() -> None:
    """Keep a folder of the current directory from hiding one of this project's packages.

    ``python -m`` puts the current directory first on ``sys.path``. A folder there named like one of our
    packages but without ``__init__.py`` (a user's ``fmus/`` of downloaded FMUs, say) becomes a namespace
    package, and with an editable install (whose finder comes after the path) it wins over ours: ``fmus``
    then had no ``__file__`` and ``run`` died with a TypeError. Only in that case, the folder holding this
    package (where its sibling packages are) goes right after the current directory, so that ours are found.
    """
    home = Path(__file__).resolve().parent.parent
    for name in ("flexarm", "fmus", "fmu_build"):
        theirs = Path.cwd() / name
        if theirs.is_dir() and not (theirs / "__init__.py").is_file() and (home / name / "__init__.py").is_file():
            if str(home) not in sys.path[:2]:
                sys.path.insert(1, str(home))
            return


_unshadow_packages()
