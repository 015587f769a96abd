"""The platform's folder for a user's caches, where flexarm-fmi keeps what it builds once per machine."""

from __future__ import annotations

import os
import sys
from pathlib import Path


def user_cache_folder(*parts: str) -> Path:
    """``$XDG_CACHE_HOME`` or ``~/.cache`` (``~/Library/Caches`` on macOS, ``%LOCALAPPDATA%`` on Windows) +
    ``flexarm-fmi`` + `parts`."""
    if sys.platform == "win32":
        base = Path(os.environ.get("LOCALAPPDATA") or Path.home() / "AppData" / "Local")
    elif sys.platform == "darwin":
        base = Path.home() / "Library" / "Caches"
    else:
        base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base.joinpath("flexarm-fmi", *parts)
