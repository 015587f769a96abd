"""Numba's on-disk cache for a Python FMU's kernels, kept across unpackings of the same FMU build.

A master unpacks an FMU into a new temporary folder for each run. Numba caches compiled kernels beside their
source (``__pycache__``) or under a folder named after the source's path, so every unpacking of the Python
plant FMU compiled its kernels again (about 20 s per run). Inside an FMU the bundled modules carry a name
private to the FMU build, ``_flexarm_<fmu>_<digest>`` (:mod:`fmu_build.isolate`; the digest covers the FMU's
sources and data), so a kernel of such a module is cached in a folder of that name under the user's cache
directory: every unpacking of the same build finds its kernels, and a different build never does. Modules
with other names (a checkout, an installed package) keep Numba's own locators.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

from .user_cache import user_cache_folder

#: A private module name of an FMU build: ``_<name>_<fmu>_<first 12 hex digits of the build digest>``.
_BUILD_PACKAGE = re.compile(r"^_\w+_[0-9a-f]{12}$")


def cache_root() -> Path:
    """Where the kernels of FMU builds are cached: ``$NUMBA_CACHE_DIR/flexarm-fmus`` when that is set, else the
    platform's user cache folder (``$XDG_CACHE_HOME`` or ``~/.cache``; ``~/Library/Caches``;
    ``%LOCALAPPDATA%``) + ``flexarm-fmi/numba``."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return Path(os.environ["NUMBA_CACHE_DIR"]) / "flexarm-fmus"
    return user_cache_folder("numba")


def keep_cache_per_build() -> None:
    """Put a locator for modules of FMU builds first in Numba's list (once per process)."""
    from numba.core import caching

    impl = getattr(caching, "CacheImpl", None) or caching._CacheImpl  # renamed in Numba 0.62
    if any(getattr(c, "flexarm_build_locator", False) for c in impl._locator_classes):
        return

    class BuildCacheLocator(caching._SourceFileBackedLocatorMixin, caching._CacheLocator):
        """Cache of a kernel of a module of an FMU build: one folder per build, stamped with the build's name."""

        flexarm_build_locator = True

        def __init__(self, py_func, py_file):
            self._py_file = py_file
            self._lineno = py_func.__code__.co_firstlineno
            self._package = py_func.__module__.partition(".")[0]
            self._cache_path = str(cache_root() / self._package)

        def get_cache_path(self):
            return self._cache_path

        def get_source_stamp(self):
            # The build's name already stands for its sources (the digest); a file's time or path would
            # change with every unpacking.
            return self._package

        @classmethod
        def from_function(cls, py_func, py_file):
            if not _BUILD_PACKAGE.match(getattr(py_func, "__module__", "").partition(".")[0]):
                return None
            return super().from_function(py_func, py_file)  # None where the folder is not writable

    impl._locator_classes.insert(0, BuildCacheLocator)
