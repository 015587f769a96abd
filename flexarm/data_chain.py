"""Every committed data file, read through its own verifying loader: the data chain of a run.

:func:`verify_data_files` is what a run calls before anything else (``scenarios.run.setup.verify_data_chain``).
It reads, with the loaders that check each one:

- the parameter file (``sandia_arm.toml``) and the sensor settings (``sensors_default.toml``): parsed and
  range-checked; they are the chain's roots, so their provenance is their SHA-256 in the results;
- the trajectory (``trajectory.npz``): against the SHA-256 its sealed ``trajectory.json`` records, and against
  the parameter file it was made from;
- every gain schedule (``gains/*``), LQG design (``lqg/lqg_*``) and payload bank (``lqg/bank_*``): each npz
  against its sealed JSON, and each against the trajectory and parameter files it was made from;
- every ``.json`` through its seal (the SHA-256 of its own bytes, :func:`flexarm.provenance.read_sealed_json`),
  so an edited value in a provenance file (a bank's sample time, say) is refused too.

It returns the SHA-256 of every ``.npz``, ``.json`` and ``.toml`` under ``flexarm/data`` for the results'
``data_sha256``. Any failure is a :class:`DataChainError` naming the file and the command that regenerates it.
"""

from __future__ import annotations

from pathlib import Path

from .parameters import DATA_DIR, DEFAULT_PARAMETER_FILE
from .provenance import DataFileError, sha256_file, sha256_memo

__all__ = ["DATA_SUFFIXES", "DataChainError", "data_files", "verify_data_files"]

#: The kinds of file a run reads from flexarm/data (figures such as trajectory.png are not read).
DATA_SUFFIXES = (".npz", ".json", ".toml")


class DataChainError(ValueError):
    """A data file is missing, corrupt, edited, or made from inputs that have changed since."""


def data_files(data_dir: Path = DATA_DIR) -> list[Path]:
    """Every file a run may read from ``data_dir`` (suffixes :data:`DATA_SUFFIXES`), sorted."""
    return sorted(p for p in Path(data_dir).rglob("*") if p.is_file() and p.suffix in DATA_SUFFIXES
                  and not p.name.startswith("."))


def relative_path(path: Path, root: Path) -> str:
    """`path` relative to `root` with forward slashes (a key of the data chain, the same on every OS); as it is
    when outside `root`."""
    path = Path(path)
    return path.relative_to(root).as_posix() if path.is_relative_to(root) else str(path)


def verify_data_files(root: Path | None = None) -> dict[str, str]:
    """Read and check every file of ``flexarm/data`` (see the module docstring); file -> SHA-256.

    Parameters
    ----------
    root : Path, optional
        Keys of the returned dict are relative to it (default: the repository).

    Raises
    ------
    DataChainError
        The loader's message, which names the file (and what regenerates it).
    """
    with sha256_memo():  # each record names the trajectory and parameter file: hashed once, not once per record
        return _verify(Path(root) if root is not None else DATA_DIR.parent.parent)


def _verify(root: Path) -> dict[str, str]:
    from .gain_schedule import read_design_metadata
    from .gain_sets import GainError
    from .lqg_bank import BANK_SCHEDULES
    from .lqg_design import DEFAULT_LQG_DIR
    from .lqr import DEFAULT_GAIN_DIR
    from .parameters import ParameterError, load_parameters
    from .provenance import read_sealed_json
    from .sensors import DEFAULT_SENSOR_FILE, SensorSettings, SensorSettingsError
    from .trajectory import TrajectoryError, load_trajectory
    from .trajectory.io import DEFAULT_TRAJECTORY_FILE
    from .trajectory.io import REGENERATE_COMMAND as CHAIN_COMMAND

    files = data_files(DATA_DIR)
    reading = DEFAULT_PARAMETER_FILE
    try:
        load_parameters(DEFAULT_PARAMETER_FILE)
        reading = DEFAULT_SENSOR_FILE
        SensorSettings.from_toml(DEFAULT_SENSOR_FILE)
        reading = DEFAULT_TRAJECTORY_FILE
        load_trajectory(DEFAULT_TRAJECTORY_FILE)
        # Gain schedules and LQG designs: the arrays' SHA-256 against the sealed JSON (and its inputs'); loading
        # them would add decompression time only (24 gain files: 0.1 s of every run's start), the laws loading the
        # ones they use where they use them.
        for npz in sorted(DEFAULT_GAIN_DIR.glob("*.npz")):
            reading = npz
            read_design_metadata(npz.with_suffix(".json"), npz)
        for npz in sorted(DEFAULT_LQG_DIR.glob("*.npz")):
            reading = npz
            read_design_metadata(npz.with_suffix(".json"), npz)
        for schedule in BANK_SCHEDULES:
            if not (DEFAULT_LQG_DIR / f"bank_{schedule}.npz").is_file():
                raise DataChainError(f"data chain: {DEFAULT_LQG_DIR / f'bank_{schedule}.npz'} is missing; "
                                     f"regenerate it with `{CHAIN_COMMAND}`")
        for js in files:  # every JSON sealed, also one whose npz is gone or that no loader above reads
            if js.suffix == ".json":
                reading = js
                read_sealed_json(js, CHAIN_COMMAND)
                npz = js.with_suffix(".npz")
                if not npz.is_file():
                    raise DataChainError(f"{js}: the data file it describes, {npz.name}, is missing; regenerate "
                                         f"it with `{CHAIN_COMMAND}`")
    except DataChainError:
        raise
    except (TrajectoryError, GainError, ParameterError, SensorSettingsError, DataFileError) as exc:
        raise DataChainError(f"data chain: {exc}") from exc
    except (OSError, ValueError, KeyError, TypeError, IndexError) as exc:  # a file a loader cannot even parse
        raise DataChainError(f"data chain: {reading}: cannot be read ({type(exc).__name__}: {exc}); regenerate "
                             f"the data with `{CHAIN_COMMAND}` (or restore it from git)") from exc
    return {relative_path(f, root): sha256_file(f) for f in files}
