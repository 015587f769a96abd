"""A controller FMU with a learned feedforward correction inside it (:mod:`flexarm.ilc`).

The correction is a design-file pair (``.npz`` + sealed ``.json``, :func:`flexarm.ilc.write_learned_feedforward`);
packed into the FMU's ``resources/`` as :data:`flexarm.ilc.LEARNED_RESOURCE`, it is read by both kinds of our
controllers at every initialisation. So the learned controller is one self-contained file: no String parameter,
no path outside the FMU, and every FMI tool runs it (``python -m scenarios run ilc_payload`` writes it as
``learned_controller.fmu``; each ILC trial runs such a copy).
"""

from __future__ import annotations

import os
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


def with_learned_feedforward(fmu: Path, correction: Path | None, out: Path) -> Path:
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

    Returns
    -------
    Path
        `out`.
    """
    stem = None
    if correction is not None:
        stem = Path(correction).with_suffix("")
        read_learned_feedforward(stem)  # refuses a stale, edited or malformed file before it is packed
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
