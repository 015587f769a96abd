"""The data of the arm carrying a known payload: the slew re-planned for it and the gains designed along it, no FMI.

The committed data (``flexarm/data``: the paper's slew and the gains along it) are the unloaded arm's. A robot that
repeats a motion with a payload re-plans the minimum-time slew for what it carries and designs its feedback along
that slew, then learns what the model still gets wrong (:mod:`flexarm.ilc`). :func:`write_payload_data` writes such a
*data folder*, laid out as ``flexarm/data`` so that a controller can run on it in place of the package's:

* ``trajectory.npz``/``.json``: the slew re-planned by FATROP from the committed one
  (:func:`flexarm.trajectory.replan_minimum_time`), with its plant replay and constraint checks in the metadata, as
  ``python -m flexarm.trajectory --replan`` writes it;
* ``sandia_arm.toml``: the parameter file (a copy of the package's, unchanged: the payload is the model's
  ``payload_mass``, recorded in every design);
* ``gains/<set>_<schedule>``: the LQR schedules of the four weight sets (:data:`flexarm.gain_sets.WEIGHT_NAMES`)
  and the three schedules, designed on the loaded arm along the re-planned slew;
* ``lqg/lqg_<schedule>``: the LQG designs (the controllers' predictor over a measured loop delay);
* ``payload_data.json``: what the folder is (payload, the committed slew and parameter file it came from, the
  SHA-256 of each file, the commit), sealed.

The designs record their trajectory as ``flexarm/data/trajectory.npz`` with its SHA-256: within this folder that is
the folder's own slew (:func:`flexarm.gain_schedule.read_design_metadata` with ``data_dir``), and packed into a
controller FMU it is the FMU's. The folder carries no discrete-time (``dlqr-``) sets and no payload bank: it serves
the controllers with continuous-time gains.
"""

from __future__ import annotations

import datetime as _dt
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

from .gain_schedule import SCHEDULES, GainSchedule, design_schedule, read_design_metadata
from .gain_sets import WEIGHT_NAMES
from .parameters import DEFAULT_PARAMETER_FILE
from .provenance import DataFileError, git_commit, read_sealed_json, sha256_file, write_sealed_json

#: The manifest of a payload data folder.
MANIFEST = "payload_data.json"
FORMAT = "flexarm-payload-data/1"
#: How a design in the folder names its trajectory and parameter file: the data folder's own (see module doc).
TRAJECTORY_RECORD = "flexarm/data/trajectory.npz"
PARAMETER_RECORD = f"flexarm/data/{DEFAULT_PARAMETER_FILE.name}"


class PayloadDataError(RuntimeError):
    """A payload data folder that cannot be written or does not hold what its manifest says."""


@dataclass(frozen=True)
class PayloadData:
    """A payload data folder (:func:`write_payload_data`).

    Attributes
    ----------
    folder : Path
    payload_mass : float
        kg.
    manifest : dict
        ``payload_data.json``.
    """

    folder: Path
    payload_mass: float
    manifest: dict

    @property
    def trajectory_file(self) -> Path:
        return self.folder / "trajectory.npz"

    def trajectory(self):
        """The re-planned slew (:class:`flexarm.trajectory.TrajectoryResult`), checked against its parameter file."""
        from .trajectory import load_trajectory

        return load_trajectory(self.trajectory_file)

    def gains(self, name: str, schedule: str = "200ms") -> GainSchedule:
        """A gain schedule along the re-planned slew, its data chain checked against this folder."""
        return GainSchedule.load(name, schedule, directory=self.folder / "gains")

    def files(self) -> list[Path]:
        """Every data file of the folder (the manifest's), paths."""
        return [self.folder / rel for rel in sorted(self.manifest["files"])]


def _source() -> dict:
    from .trajectory import DEFAULT_TRAJECTORY_FILE

    return {"source_trajectory_sha256": sha256_file(DEFAULT_TRAJECTORY_FILE),
            "parameter_sha256": sha256_file(DEFAULT_PARAMETER_FILE)}


def read_payload_data(folder) -> PayloadData:
    """Read a payload data folder, checking every file against its manifest and every design's chain.

    Raises
    ------
    PayloadDataError
        Missing or edited manifest or file, or a design whose trajectory is not the folder's.
    """
    folder = Path(folder)
    try:
        manifest = read_sealed_json(folder / MANIFEST, "python -m flexarm.payload_data --payload KG --out FOLDER")
    except (DataFileError, OSError, ValueError) as exc:
        raise PayloadDataError(f"payload data {folder}: {exc}") from exc
    if manifest.get("format") != FORMAT:
        raise PayloadDataError(f"payload data {folder}: format {manifest.get('format')!r}, expected {FORMAT!r}")
    for rel, sha in manifest.get("files", {}).items():
        p = folder / rel
        if not p.is_file() or sha256_file(p) != sha:
            raise PayloadDataError(f"payload data {folder}: {rel} is missing or differs from its manifest")
    traj_sha = manifest["files"].get("trajectory.npz")
    for json_path in sorted(folder.glob("*/*.json")):
        meta = read_design_metadata(json_path, json_path.with_suffix(".npz"), data_dir=folder)
        if meta.get("trajectory_sha256") != traj_sha:
            raise PayloadDataError(f"payload data {folder}: {json_path.relative_to(folder)} was designed along "
                                   "another slew than the folder's")
    return PayloadData(folder, float(manifest["payload_mass_kg"]), manifest)


def write_payload_data(payload_mass: float, folder, progress=print) -> PayloadData:
    """Write (or reuse) the data folder of the arm carrying `payload_mass` (kg): re-planned slew, gains, LQG designs.

    An existing folder written for the same payload from the same committed slew and parameter file, with every
    file as its manifest says, is reused (a resumed learning run gets the data it started with); anything else in
    `folder` is replaced, atomically (the new folder is written beside it and renamed). About a minute of CPU:
    the re-plan half a minute (FATROP), each of the 12 gain schedules about a second.

    Raises
    ------
    PayloadDataError
        The payload is out of range; flexarm.trajectory.TrajectoryError when the re-plan fails.
    """
    import math

    if not (isinstance(payload_mass, (int, float)) and math.isfinite(payload_mass) and 0.0 <= payload_mass <= 10.0):
        raise PayloadDataError(f"payload_mass: a payload in [0, 10] kg, got {payload_mass!r}")
    folder = Path(folder)
    if (folder / MANIFEST).is_file():
        try:
            data = read_payload_data(folder)
        except Exception as exc:  # noqa: BLE001 - any defect of an old folder: it is written anew, and said so
            progress(f"payload data {folder}: not reused ({exc})")
        else:
            if data.payload_mass == float(payload_mass) and all(data.manifest.get(k) == v for k, v in
                                                                _source().items()):
                progress(f"payload data {folder}: reused ({payload_mass:g} kg, t_f {data.manifest['t_f_s']:.3f} s)")
                return data
            progress(f"payload data {folder}: written for another payload or slew; writing it anew")
    folder.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", dir=folder.parent))
    try:
        manifest = _write(float(payload_mass), tmp, progress)
        old = folder.with_name(f".{folder.name}.old")
        if folder.exists():
            os.replace(folder, old)
        os.replace(tmp, folder)
        shutil.rmtree(old, ignore_errors=True)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return PayloadData(folder, float(payload_mass), manifest)


def _write(payload_mass: float, folder: Path, progress) -> dict:
    from .lqg_design import design_lqg
    from .model import ArmModel
    from .parameters import load_parameters
    from .progress import heartbeat
    from .trajectory import load_trajectory, save_trajectory
    from .trajectory.report import annotate_with_replay
    from .trajectory.solve import replan_minimum_time

    params = load_parameters(payload_mass=payload_mass)
    shutil.copy2(DEFAULT_PARAMETER_FILE, folder / DEFAULT_PARAMETER_FILE.name)
    progress(f"payload data: re-planning the slew for {payload_mass:g} kg (FATROP: its solver made, then two solves)")
    with heartbeat("payload data: re-planning", emit=progress):  # about 10 CPU-s of FATROP, silent
        result = replan_minimum_time(params, load_trajectory(), verbose=False)
    replay = annotate_with_replay(result, params)
    traj_file = folder / "trajectory.npz"
    save_trajectory(result, traj_file)
    progress(f"payload data: t_f {result.t_f:.3f} s; replay in the loaded plant: max angle error "
             f"{replay['max_angle_error_deg']:.4f} deg")
    model = ArmModel(params)
    for name in WEIGHT_NAMES:
        progress(f"payload data: gains {name} (200ms, 20ms, single) along the re-planned slew")
        for schedule in SCHEDULES:
            s = design_schedule(model, traj_file, name, schedule)
            s.metadata.update(trajectory_file=TRAJECTORY_RECORD, parameter_file=PARAMETER_RECORD)
            s.save(folder / "gains")
    progress("payload data: LQG designs (the predictor over a measured loop delay)")
    for schedule in SCHEDULES:
        d = design_lqg(model, traj_file, schedule)
        d.metadata.update(trajectory_file=TRAJECTORY_RECORD, parameter_file=PARAMETER_RECORD)
        (folder / "lqg").mkdir(exist_ok=True)
        d.save(folder / "lqg")
    files = {p.relative_to(folder).as_posix(): sha256_file(p) for p in sorted(folder.rglob("*")) if p.is_file()}
    manifest = {"format": FORMAT, "payload_mass_kg": payload_mass, **_source(), "t_f_s": float(result.t_f),
                "description": "the slew re-planned for the payload and the gains along it (flexarm.payload_data)",
                "files": files, "commit": git_commit(),
                "created_utc": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")}
    write_sealed_json(folder / MANIFEST, manifest)
    return manifest


def main(argv=None) -> int:
    """``python -m flexarm.payload_data --payload KG --out FOLDER``: write (or reuse) a payload data folder."""
    import argparse
    import sys

    ap = argparse.ArgumentParser(prog="python -m flexarm.payload_data", description=__doc__.split("\n")[0])
    ap.add_argument("--payload", type=float, required=True, help="tip payload, kg, in [0, 10]")
    ap.add_argument("--out", required=True, help="the data folder to write (reused when it holds this payload's)")
    args = ap.parse_args(argv)
    from .trajectory import TrajectoryError

    try:
        data = write_payload_data(args.payload, args.out, progress=lambda s: print(s, flush=True))
    except PayloadDataError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except TrajectoryError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(f"wrote {data.folder} ({len(data.files())} files, t_f {data.manifest['t_f_s']:.3f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
