"""Build tooling of the project's FMUs (installable; ``build_fmus.py`` at the top is a thin entry point).

Modules: :mod:`~fmu_build.registry` (one entry per FMU, source and output folders),
:mod:`~fmu_build.compile` (the C front end), :mod:`~fmu_build.package` (stage, build,
finish, validate), :mod:`~fmu_build.docs` (each FMU's documentation/index.html),
:mod:`~fmu_build.interface_doc` (the variable tables of docs/fmu-interface.md),
:mod:`~fmu_build.native` (the native kind: up-to-date checks around fmu_build.native_build) and
:mod:`~fmu_build.cli` (``python -m fmu_build`` / ``python build_fmus.py``).

Add an FMU: write its slave script under ``fmus/<kind>/`` (a :class:`FlexarmSlave`
subclass in a module with a unique name) and add one :class:`~fmu_build.registry.FmuSpec`
to :data:`~fmu_build.registry.FMUS`, naming the data files it reads.
"""

from .compile import BuildError
from .native import build_native_all, default_native_out_dir
from .package import build_all, build_fmu, interfaces
from .registry import FMUS, FmuSpec, default_out_dir

__all__ = ["FMUS", "BuildError", "FmuSpec", "build_all", "build_fmu", "build_native_all", "default_native_out_dir",
           "default_out_dir", "interfaces"]
