"""Compile the FMUs' C front end (``fmus/common/fmi2_shim*.c``) for one FMU.

The front end is built with the C compiler (``$CC``, default ``gcc``) against
fmpy's FMI 2.0 headers, with the FMU's GUID, model identifier and the file name
of the Python shared library it loads in a native host built in. That name comes
from the building Python's ``sysconfig`` (``INSTSONAME``), so the FMU asks for the
libpython of the Python it was built with.
"""

from __future__ import annotations

import os
import platform
import shutil
import subprocess
import sys
import sysconfig
import warnings
from pathlib import Path

from .registry import NATIVE_COMMON_DIR, SHIM_SOURCES, SOURCES


class BuildError(RuntimeError):
    """An FMU could not be built or failed validation."""


def check_platform() -> None:
    """BuildError unless this is Linux x86-64 (the only binaries/ platform the FMUs carry)."""
    if sys.platform != "linux" or platform.machine() not in ("x86_64", "AMD64"):
        raise BuildError(f"the FMUs are built for Linux x86-64 (binaries/linux64) only; this is {sys.platform} "
                         f"{platform.machine()}")


def c_compiler() -> str:
    """Path of the C compiler that builds the FMI front end (``$CC``, default ``gcc``); BuildError if none."""
    cc = os.environ.get("CC") or "gcc"
    path = shutil.which(cc)
    if path is None:
        raise BuildError(
            f"no C compiler: {cc!r} is not on PATH. Building the FMUs compiles their FMI front end "
            f"({', '.join(str(p.relative_to(SOURCES)) for p in SHIM_SOURCES)} in {SOURCES}) with a C compiler; "
            "install gcc (Debian/Ubuntu: 'sudo apt-get install gcc') or set CC to a C compiler.")
    return path


def fmi_headers() -> Path:
    """Folder with the FMI 2.0 C headers (fmpy ships them)."""
    import fmpy

    folder = Path(fmpy.__file__).parent / "c-code"
    if not (folder / "fmi2Functions.h").is_file():
        raise BuildError(f"the FMI 2.0 headers are not in {folder} (fmpy {fmpy.__version__}); "
                         "install an fmpy that ships its c-code folder")
    return folder


def libpython_name() -> str:
    """File name of this Python's shared library (e.g. ``libpython3.11.so.1.0``), from ``sysconfig``."""
    name = sysconfig.get_config_var("INSTSONAME") or sysconfig.get_config_var("LDLIBRARY")
    if not name or not str(name).endswith((".so", ".so.1.0")) and ".so" not in str(name):
        raise BuildError(f"this Python ({sys.executable}) has no shared library (sysconfig INSTSONAME = {name!r}); "
                         "the FMUs embed Python in the host and need a Python built with --enable-shared")
    return str(name)


def compile_shim(guid: str, model_identifier: str, dest: Path, preflight: str = "flexarm_fmu_preflight.py",
                 cflags: tuple[str, ...] = ()) -> Path:
    """Compile the front end for one FMU into `dest` (a .so); BuildError with the compiler's output.

    `preflight` is the file name (in the FMU's ``resources``) of the start-up check the front end runs;
    `cflags` are added to the compiler's (the tests build it with the sanitizers).
    """
    if not all(c.isalnum() or c in "-{}" for c in guid) or not model_identifier.isidentifier() \
            or not (preflight.endswith(".py") and preflight[:-3].isidentifier()):
        raise BuildError(f"unexpected GUID {guid!r}, model identifier {model_identifier!r} or start-up check "
                         f"{preflight!r}")
    version = f"{sys.version_info.major}.{sys.version_info.minor}"
    # -ffile-prefix-map: no path of this checkout in the binary (__FILE__), so the same sources give the same bytes
    # wherever they are built
    cmd = [c_compiler(), "-std=c11", "-O2", *cflags, "-fPIC", "-shared", "-fvisibility=hidden", "-Wall", "-Wextra",
           f"-ffile-prefix-map={SOURCES}=.", f"-ffile-prefix-map={fmi_headers()}=fmi2",
           f"-I{fmi_headers()}", f"-I{SOURCES / 'common'}", f"-I{NATIVE_COMMON_DIR}", f'-DFLEXARM_FMU_GUID="{guid}"',
           f'-DFLEXARM_MODEL_IDENTIFIER="{model_identifier}"', f'-DFLEXARM_LIBPYTHON="{libpython_name()}"',
           f'-DFLEXARM_PYTHON_VERSION="{version}"', f'-DFLEXARM_PREFLIGHT_FILE="{preflight}"',
           "-o", str(dest), *map(str, SHIM_SOURCES), "-ldl", "-lpthread"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise BuildError(f"compiling the FMI front end failed:\n  {' '.join(cmd)}\n{proc.stderr.strip()}")
    if proc.stderr.strip():
        warnings.warn(f"FMI front end: compiler warnings:\n{proc.stderr.strip()}", stacklevel=2)
    return dest
