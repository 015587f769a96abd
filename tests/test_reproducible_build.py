"""Two builds of the same sources give byte-identical FMUs, both kinds (issue 35: provenance means what it says).

One FMU of each kind, built twice into separate folders (a native FMU for all its platforms from each build's
Python twin): the SHA-256 of the .fmu files are equal, so a sweep's "ran on other FMU builds" means other sources.
What made builds differ before: pythonfmu's time-based GUID and generation date (in the description, the front end
compiled with the GUID, the documentation page).
"""

from __future__ import annotations

import hashlib
import zipfile

from fmu_build import build_all
from fmu_build.native_build import PLATFORMS, build_native_fmus


def _sha(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _differing(a, b) -> list[str]:
    with zipfile.ZipFile(a) as za, zipfile.ZipFile(b) as zb:
        names = za.namelist()
        if names != zb.namelist():
            return ["the member list or its order"]
        return [n for n in names if za.read(n) != zb.read(n) or za.getinfo(n).date_time != zb.getinfo(n).date_time]


def test_two_builds_of_one_commit_are_byte_identical(tmp_path):
    built = []
    for i in range(2):
        python = build_all(tmp_path / f"py{i}", only=["sensors"], force=True)
        native = build_native_fmus(tmp_path / f"native{i}", python, only=["sensors"], platforms=tuple(PLATFORMS))
        built.append((python["sensors"], native["sensors"]))
    for (a, b), kind in zip(zip(*built), ("python", "native")):
        assert _sha(a) == _sha(b), (kind, _differing(a, b))
    with zipfile.ZipFile(built[0][0]) as z:  # the GUID is the content's, not the clock's
        assert b"generationDateAndTime" not in z.read("modelDescription.xml")
