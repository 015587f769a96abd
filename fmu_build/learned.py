"""A controller FMU with a learned feedforward correction inside it (:mod:`flexarm.ilc`).

The correction is a design-file pair (``.npz`` + sealed ``.json``, :func:`flexarm.ilc.write_learned_feedforward`);
packed into the FMU's ``resources/`` as :data:`flexarm.ilc.LEARNED_RESOURCE`, it is read by both kinds of our
controllers at every initialisation. So the learned controller is one self-contained file: no String parameter,
no path outside the FMU, and every FMI tool runs it (``python -m scenarios run ilc_payload`` writes it as
``learned_controller.fmu``; each ILC trial runs such a copy).
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

from flexarm.learned_feedforward import LEARNED_RESOURCE, read_learned_feedforward

from .package import ZIP_DATE
from .registry import NATIVE_SUFFIX

#: Model identifiers of our controllers that add a learned correction to a feedforward (controller_fb has none);
#: their native twins (the same with :data:`fmu_build.registry.NATIVE_SUFFIX`) do too.
LEARNING_CONTROLLERS = ("FlexarmController", "FlexarmControllerFF", "FlexarmControllerDLQR", "FlexarmControllerLQG")


def reads_learned_feedforward(model_identifier: str) -> bool:
    """Whether the FMU of this model identifier (either kind) adds a learned correction to its feedforward."""
    return model_identifier.removesuffix(NATIVE_SUFFIX) in LEARNING_CONTROLLERS


def with_learned_feedforward(fmu: Path, correction: Path | None, out: Path, data_dir=None) -> Path:
    """Write to `out` a copy of the controller FMU `fmu` carrying the learned correction `correction`.

    Parameters
    ----------
    fmu : Path
        One of our controller FMUs (:data:`LEARNING_CONTROLLERS`), either kind.
    correction : Path or None
        The ``.npz`` of a learned-feedforward file (its ``.json`` beside it); checked first
        (:func:`flexarm.ilc.read_learned_feedforward`). None: a copy without any correction.
    out : Path
        The new FMU (written atomically). Every member of `fmu` is copied unchanged except a learned correction it
        already carried; the same inputs give the same bytes.
    data_dir : path-like, optional
        The payload data folder the correction was learnt on (:mod:`flexarm.payload_data`), when not the package's.

    Returns
    -------
    Path
        `out`.
    """
    stem = None
    if correction is not None:
        stem = Path(correction).with_suffix("")
        read_learned_feedforward(stem, data_dir)  # refuses a stale, edited or malformed file before it is packed
    ours = {f"resources/{LEARNED_RESOURCE}", f"resources/{Path(LEARNED_RESOURCE).with_suffix('.json')}"}
    out = Path(out)
    tmp = out.with_name(f".{out.name}.partial")
    with zipfile.ZipFile(fmu) as src, zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as dst:
        for info in src.infolist():
            if info.filename not in ours:
                dst.writestr(info, src.read(info))
        for suffix in (".npz", ".json") if stem is not None else ():
            info = zipfile.ZipInfo(f"resources/{Path(LEARNED_RESOURCE).with_suffix(suffix)}", date_time=ZIP_DATE)
            info.external_attr = 0o644 << 16
            info.compress_type = zipfile.ZIP_DEFLATED
            dst.writestr(info, stem.with_suffix(suffix).read_bytes())
    os.replace(tmp, out)  # atomic: a reader sees the old file or the whole new one
    return out


#: Our controllers (model identifiers, Python kind) that run on a payload data folder (:mod:`flexarm.payload_data`):
#: those whose law is the trajectory's feedforward and the continuous-time gains along it (native kind:
#: :func:`native_with_payload_data`).
PAYLOAD_DATA_CONTROLLERS = ("FlexarmController", "FlexarmControllerFF")


def native_with_payload_data(name: str, python_fmu: Path, data, out: Path) -> Path:
    """The native controller `name` (``controller`` or ``controller_ff``) built on the payload data folder `data`
    (:func:`fmu_build.native_build.build_native_fmu`, every platform; a few seconds): its resources are the
    folder's slew, gains and LQG designs, and a learned correction must have been learnt on that slew. Written to
    `out`; `python_fmu` is its Python twin (the interface)."""
    from .native_build import build_native_fmu

    out = Path(out)
    return build_native_fmu(name, Path(python_fmu), out.parent, data_dir=data.folder, file_name=out.stem)


def _with_stop_time(description: str, stop_time: float) -> str:
    """modelDescription.xml with its DefaultExperiment's stopTime set to the slew's duration (a tool that runs the
    FMU by its default experiment runs the re-planned slew, not the paper's). Only that attribute changes: the
    variables, and so the GUID the binaries check, stay the original's."""
    head, tag, rest = description.partition("<DefaultExperiment")
    element, end, tail = rest.partition(">")
    changed, n = re.subn(r'stopTime="[^"]*"', f'stopTime="{stop_time!r}"', element)
    if not tag or n != 1:
        raise ValueError("modelDescription.xml: no DefaultExperiment with one stopTime to set")
    return head + tag + changed + end + tail


def with_payload_data(fmu: Path, data, out: Path) -> Path:
    """Write to `out` a copy of the Python controller FMU `fmu` that runs on the payload data folder `data`.

    The FMU's own data folder (``resources/<its flexarm package>/data``) gets the folder's re-planned slew and the
    gains and LQG designs along it in place of the package's; every other member is copied unchanged, so the
    FMU's law follows the re-planned slew with no parameter and no path outside the FMU. The designs that the
    folder does not hold (discrete-time sets, payload banks) are left out rather than left stale.

    Parameters
    ----------
    fmu : Path
        :data:`PAYLOAD_DATA_CONTROLLERS`, Python kind.
    data : flexarm.payload_data.PayloadData
        Read and checked (:func:`flexarm.payload_data.read_payload_data`).
    out : Path
        Written atomically; the same inputs give the same bytes.

    Raises
    ------
    ValueError
        Another FMU, or a parameter file other than the FMU's.
    """
    from flexarm.payload_data import MANIFEST

    with zipfile.ZipFile(fmu) as src:
        names = src.namelist()
        if "resources/flexarm_bundle.json" not in names:
            raise ValueError(f"{fmu}: not a Python-kind FMU of ours (no resources/flexarm_bundle.json); a payload "
                             "data folder is packed into the Python kind")
        package = json.loads(src.read("resources/flexarm_bundle.json")).get("package", "flexarm")
        ident = ET.fromstring(src.read("modelDescription.xml")).find("CoSimulation").get("modelIdentifier")
        if ident not in PAYLOAD_DATA_CONTROLLERS:
            raise ValueError(f"{fmu}: {ident} does not run on a payload data folder (which holds the slew and its "
                             f"continuous-time gains); allowed: {', '.join(PAYLOAD_DATA_CONTROLLERS)}")
        own = f"resources/{package}/data/"
        params = f"{own}{data.folder.joinpath('sandia_arm.toml').name}"
        if params not in names or src.read(params) != (data.folder / "sandia_arm.toml").read_bytes():
            raise ValueError(f"{data.folder}: its parameter file is not the one {fmu.name} was built with")
        new = {p.relative_to(data.folder).as_posix(): p.read_bytes() for p in data.files() + [data.folder / MANIFEST]
               if p.name != "sandia_arm.toml"}
        gone = {n[len(own):] for n in names if n.startswith((f"{own}gains/", f"{own}lqg/"))}
        gone |= {"trajectory.npz", "trajectory.json"}
        # the bundle's manifest lists every data file with its SHA-256, which the FMU checks at instantiation
        info = json.loads(src.read("resources/flexarm_bundle.json"))
        info["data_sha256"] = {**{k: v for k, v in info["data_sha256"].items() if k not in gone},
                               **{rel: hashlib.sha256(b).hexdigest() for rel, b in sorted(new.items())}}
        info["flexarm_files"] = ([f for f in info["flexarm_files"] if f.removeprefix("data/") not in gone]
                                 + [f"data/{rel}" for rel in sorted(new)])
        tree = hashlib.sha256()  # flexarm_fmu_preflight.tree_sha256 over the files as they now are
        for rel in info["flexarm_files"]:
            short = rel.removeprefix("data/")
            body = new[short] if rel.startswith("data/") and short in new else src.read(f"resources/{package}/{rel}")
            tree.update(rel.encode() + b"\0" + body + b"\0")
        info["flexarm_sha256"] = tree.hexdigest()
        info["slew"] = dict(info["slew"], duration=round(float(data.manifest["t_f_s"]), 9))
        info["payload_data"] = {"payload_mass_kg": data.payload_mass,
                                "trajectory_sha256": data.manifest["files"]["trajectory.npz"]}
        description = _with_stop_time(src.read("modelDescription.xml").decode(), info["slew"]["duration"])
        out = Path(out)
        tmp = out.with_name(f".{out.name}.partial")
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as dst:
            for member in src.infolist():
                if member.filename == "resources/flexarm_bundle.json":
                    dst.writestr(member, json.dumps(info, indent=1) + "\n")
                elif member.filename == "modelDescription.xml":
                    dst.writestr(member, description)
                elif member.filename[len(own):] not in gone or not member.filename.startswith(own):
                    dst.writestr(member, src.read(member))
            for rel, body in sorted(new.items()):
                member = zipfile.ZipInfo(own + rel, date_time=ZIP_DATE)
                member.external_attr = 0o644 << 16
                member.compress_type = zipfile.ZIP_DEFLATED
                dst.writestr(member, body)
    os.replace(tmp, out)
    return out
