"""Results record the code's commit: from git in a checkout, baked in at build time in an installed package,
and never the commit of some other repository the package happens to sit in."""

import re
import subprocess
from pathlib import Path

import pytest

from flexarm import provenance

HEX = re.compile(r"^[0-9a-f]{40}(\+dirty)?$")


def test_a_checkout_gives_its_head():
    if not (provenance.SOURCE_ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    assert HEX.match(provenance.git_commit())


def test_a_folder_inside_another_repository_is_not_that_repository(tmp_path):
    """A venv (or an unpacked source tree) inside a user's project must not record the project's commit."""
    subprocess.run(["git", "init", "-q", str(tmp_path)], check=True)
    subprocess.run(["git", "-C", str(tmp_path), "-c", "user.email=a@b", "-c", "user.name=a", "commit", "-q",
                    "--allow-empty", "-m", "theirs"], check=True)
    inside = tmp_path / ".venv" / "lib" / "site-packages"
    inside.mkdir(parents=True)
    assert provenance.git_commit(inside) == "unknown"
    assert HEX.match(provenance.git_commit(tmp_path))  # the top of a checkout answers


def test_an_installed_package_reports_the_commit_baked_at_build_time(tmp_path, monkeypatch):
    package = tmp_path / "site-packages"
    (package / "flexarm").mkdir(parents=True)
    baked = package / "flexarm" / "_build_commit.txt"
    monkeypatch.setattr(provenance, "SOURCE_ROOT", package)
    monkeypatch.setattr(provenance, "BUILD_COMMIT_FILE", baked)
    assert provenance.git_commit(package) == "unknown"  # nothing baked: said so, never guessed
    baked.write_text("0123456789abcdef0123456789abcdef01234567\n")
    assert provenance.git_commit(package) == "0123456789abcdef0123456789abcdef01234567"


def test_the_version_is_the_distributions():
    import importlib.metadata

    try:
        expected = importlib.metadata.version("flexarm-fmi")
    except importlib.metadata.PackageNotFoundError:
        from flexarm import __version__ as expected
    assert provenance.package_version() == expected
    assert (Path(provenance.__file__).parent / "__init__.py").read_text().count(f'"{expected}"') == 1
