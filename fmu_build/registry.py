"""The project's FMUs: one :class:`FmuSpec` per FMU (add an FMU with one entry in :data:`FMUS`).

Where the sources are: :data:`SOURCES` is the installed ``fmus`` folder (the slave
scripts, the glue in ``fmus/common``, the C front end), :data:`FLEXARM_DIR` the
installed ``flexarm`` package. Both work from a checkout and from a non-editable install.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import flexarm
import fmus

#: The FMUs' sources (slave scripts, fmus/common glue and C front end).
SOURCES = Path(fmus.__file__).resolve().parent
COMMON_DIR = SOURCES / "common"
#: The physics package bundled (in part) into every FMU.
FLEXARM_DIR = Path(flexarm.__file__).resolve().parent
#: Where the C code shared with the native FMUs lives (the table of live instances and states).
NATIVE_COMMON_DIR = SOURCES / "native" / "common"
#: The C front end's sources, compiled together into binaries/linux64/<modelIdentifier>.so.
SHIM_SOURCES = (*sorted(COMMON_DIR.glob("fmi2_shim*.c")), NATIVE_COMMON_DIR / "live_table.c")
#: Its sources and headers: what its build depends on (the up-to-date check, the FMU's recorded SHA-256).
SHIM_FILES = (*SHIM_SOURCES, *sorted(COMMON_DIR.glob("fmi2_shim*.h")), NATIVE_COMMON_DIR / "live_table.h")
#: A native FMU's model identifier: its Python twin's with this suffix (FlexarmController -> FlexarmControllerNative).
NATIVE_SUFFIX = "Native"
#: Environment variable naming the default output folder.
OUT_DIR_ENV = "FLEXARM_FMU_DIR"
#: The interface document shipped in each FMU's documentation/ (when the checkout has it).
DOC_FILE = SOURCES.parent / "docs" / "fmu-interface.md"


def default_out_dir() -> Path:
    """Where FMUs are built by default: ``$FLEXARM_FMU_DIR``, else ``build/fmus`` under the current directory."""
    return Path(os.environ.get(OUT_DIR_ENV) or Path.cwd() / "build" / "fmus")


@dataclass(frozen=True)
class FmuSpec:
    """One FMU of the project.

    Attributes
    ----------
    name : str
        Output file stem: ``<out_dir>/<name>.fmu``.
    script : Path
        Slave script; its stem is the Python module name inside the FMU and
        must be unique among all FMUs (they may share one interpreter).
    extra_files : tuple of Path
        Further modules bundled into this FMU's resources (e.g. a shared base).
    data : tuple of str
        Glob patterns, relative to ``flexarm/data``, of the data files this FMU
        reads at run time; nothing else from ``flexarm/data`` is bundled. The
        ``flexarm`` modules bundled are those the slave module imports.
    """

    name: str
    script: Path
    extra_files: tuple[Path, ...] = field(default=())
    data: tuple[str, ...] = field(default=())


#: What every FMU reads: the arm's parameters (the trajectory's first state and length are baked in at build time).
_COMMON_DATA = ("sandia_arm.toml", "signals.toml")
#: The controllers track the trajectory (its provenance file rides along for the data-chain check).
_TRAJECTORY = ("trajectory.npz", "trajectory.json")
_CONTROLLER_BASE = SOURCES / "controller" / "flexarm_controller_base.py"


def _controller(suffix: str, gains: tuple[str, ...]) -> FmuSpec:
    return FmuSpec(f"controller{suffix}", SOURCES / "controller" / f"flexarm_controller{suffix}_fmu.py",
                   (_CONTROLLER_BASE,), (*_COMMON_DATA, *_TRAJECTORY, *gains))


#: Continuous-time gain designs (controller, controller_fb) and discrete ones (controller_dlqr), with sidecars.
_CONTINUOUS_GAINS = ("gains/gamma*", "gains/eq32*")
_DISCRETE_GAINS = ("gains/dlqr-*",)
#: The LQG's designs (Kalman filter and discrete LQR per schedule point), with sidecars.
_LQG_DESIGNS = ("lqg/*",)
#: The LQG's single-filter designs only (no payload bank): the paper's laws' predictor (flexarm.lqg.PredictedTracking).
_LQG_FILTERS = ("lqg/lqg_*",)

#: Every FMU of the project. The glue in fmus/common goes into every FMU.
FMUS: dict[str, FmuSpec] = {
    spec.name: spec for spec in (
        FmuSpec("plant", SOURCES / "plant" / "flexarm_plant_fmu.py", data=_COMMON_DATA),
        FmuSpec("sensors", SOURCES / "sensors" / "flexarm_sensors_fmu.py",
                data=(*_COMMON_DATA, "sensors_default.toml")),
        # the paper's laws with feedback carry the LQG's Kalman designs: their predictor over a measured delay
        _controller("", (*_CONTINUOUS_GAINS, *_LQG_FILTERS)),
        _controller("_ff", ()),
        _controller("_fb", (*_CONTINUOUS_GAINS, *_LQG_FILTERS)),
        _controller("_dlqr", (*_DISCRETE_GAINS, *_LQG_FILTERS)),
        _controller("_lqg", _LQG_DESIGNS),
        # The slew's reference signals for a user's controller (docs/own-controller.md).
        FmuSpec("reference", SOURCES / "reference" / "flexarm_reference_fmu.py", data=(*_COMMON_DATA, *_TRAJECTORY)),
    )
}
