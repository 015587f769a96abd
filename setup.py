"""Bakes the checkout's git commit into a built package (``flexarm/_build_commit.txt``).

Everything else about the package is in pyproject.toml. A non-editable install (``pip install .``) has no
git checkout beside it, so :func:`flexarm.provenance.git_commit` reads the commit recorded here at build
time; an editable install asks git directly.
"""

import subprocess
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent


def _commit() -> str | None:
    """HEAD of the checkout this is built from ('+dirty' when tracked files differ); None outside git."""
    try:
        top = subprocess.run(["git", "rev-parse", "--show-toplevel"], cwd=ROOT, capture_output=True, text=True,
                             check=True, timeout=10).stdout.strip()
        if Path(top).resolve() != ROOT:
            return None  # a source tree inside another repository (e.g. unpacked into a project)
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True, check=True,
                              timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT,
                               capture_output=True, text=True, check=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return head + ("+dirty" if dirty else "")


class BuildPyWithCommit(build_py):
    def run(self):
        super().run()
        commit = _commit()
        if commit and not getattr(self, "editable_mode", False):
            target = Path(self.build_lib) / "flexarm" / "_build_commit.txt"
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_text(commit + "\n")


setup(cmdclass={"build_py": BuildPyWithCommit})
