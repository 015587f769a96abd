"""Result files: time series as CSV (provenance and atomic writes: :mod:`flexarm.provenance`).

A case's CSV (:func:`write_csv`) has one column per recorded signal (``<instance>.<variable>``: the plant's
states and tip, the torques, every signal wired into the controller) and the columns of
:func:`analysis_columns`: the reference of each sample (``ref.*``, what the reference FMU outputs), the arm's
joint angles (``joint.*``) and the errors (``err.* = actual - reference``). The layout is documented by
:func:`layout_table` (generated into docs/own-controller.md: ``python -m scenarios.results``).
"""

from __future__ import annotations

import re
import sys
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import orjson

from flexarm.provenance import SOURCE_ROOT, write_atomic
from flexarm.signals import signals

#: The document whose generated table lists the CSV and trajectory.npz layouts.
LAYOUT_DOC = Path(__file__).resolve().parent.parent / "docs" / "own-controller.md"
_START = "<!-- generated from flexarm/data/signals.toml by `python -m scenarios.results`: result layout -->"
_END = "<!-- end of generated result layout -->"
#: Joint quantities of the arm (actual: ``joint.<name>``; reference: ``ref.<name>_ref``).
JOINTS = (("q1", "rad", "joint-1 angle θ1"), ("q2", "rad", "joint-2 angle θ7 − θ6"),
          ("qd1", "rad/s", "joint-1 rate ω1"), ("qd2", "rad/s", "joint-2 rate ω7 − ω6"))


#: The CSV's second line starts with this: the columns' units, a comment line that readers skip
#: (``pandas.read_csv(path, comment="#")``, ``numpy.genfromtxt(path, delimiter=",", names=True)``).
UNITS_PREFIX = "# units: "


def unit_of(column: str) -> str:
    """The unit of a case CSV's column (:func:`write_csv`), from the signal catalogue; "" when unknown (an output
    of a user's FMU that the catalogue does not name) or dimensionless.

    ``time`` s; ``<instance>.<name>``, ``ref.<name>``, ``err.<name>``: the catalogue's unit of <name> (any FMU's
    output of that name); ``joint.<name>`` and ``err.<joint name>``: :data:`JOINTS`.
    """
    if column == "time":
        return "s"
    name = column.split(".", 1)[-1]
    joints = {j: unit for j, unit, _ in JOINTS}
    if column.startswith(("joint.", "err.")) and name in joints:
        return joints[name]
    return _catalogue_units().get(name, "")


def _catalogue_units() -> dict[str, str]:
    if not _UNITS:
        from flexarm.signals import catalogue

        for s in catalogue():
            _UNITS.setdefault(s.name, "" if s.unit in ("-", "1") else s.unit)
    return _UNITS


_UNITS: dict[str, str] = {}


#: What is left of a directory outside the results folder and the checkout: ``…/name`` (the file's SHA-256, recorded
#: beside it, says which file it was). An absolute POSIX or Windows path not inside a word (units such as rad/s stay).
_FOREIGN_DIRS = re.compile(r"(?<![\w.~\-/\\])(?:/|[A-Za-z]:[\\/])(?:[^\s/\\'\"<>|:]+[\\/])+")


def portable(obj, folder: str | Path, root: str | Path = SOURCE_ROOT):
    """`obj` (JSON values) with no absolute path of the machine that ran it, for a results JSON.

    In every string, a path inside the results `folder` becomes relative to it (``none.csv``), one inside the
    checkout `root` relative to that (``build/fmus/plant.fmu``, ``scenarios/table2.toml``), the home folder ``~``,
    and the folders of any other absolute path ``…/`` (an FMU of one's own, a temporary unpacking folder in an FMU's
    log): the files themselves are identified by the SHA-256 the JSON records beside them.
    """
    prefixes = []  # (absolute folder, what it becomes), the most specific first
    for base, name in ((folder, "."), (root, "."), (Path.home, "~")):
        try:
            resolved = str(Path(base() if callable(base) else base).resolve())
        except (OSError, RuntimeError):  # no home folder: nothing of it to hide
            continue
        if len(Path(resolved).parts) > 1:  # never the file system's root itself
            prefixes.append((resolved, name))

    def clean(text: str) -> str:
        for prefix, name in prefixes:
            if prefix in text:
                text = text.replace(prefix + "/", "" if name == "." else name + "/")
                text = re.sub(re.escape(prefix) + r"(?![\w.\-])", name, text)
        return _FOREIGN_DIRS.sub("…/", text)

    def walk(value):  # the prefixes are found once per call, not once per value (each a Path.resolve)
        if isinstance(value, str):
            return clean(value)
        if isinstance(value, Path):
            return clean(str(value))
        if isinstance(value, Mapping):  # a dict, or a plan's read-only view of one
            return {clean(k) if isinstance(k, str) else k: walk(v) for k, v in value.items()}
        if isinstance(value, (list, tuple)):
            return [walk(v) for v in value]
        return value

    return walk(obj)


def write_csv(path: str | Path, columns: dict[str, np.ndarray]) -> None:
    """Time series as CSV, written atomically: a header of column names, a units line (``# units: s,rad,...``,
    a comment: :data:`UNITS_PREFIX`), then one row per sample at full float precision."""
    names = list(columns)
    data = np.column_stack([np.asarray(columns[n], dtype=float) for n in names])
    head = ",".join(names) + "\n" + UNITS_PREFIX + ",".join(unit_of(n) for n in names) + "\n"
    body = csv_body(data)

    def write(f) -> None:  # two writes, not one concatenated copy of a file of megabytes
        f.write(head.encode())
        f.write(body)

    write_atomic(path, write)


def csv_body(data: np.ndarray) -> bytes:
    """The rows of a 2-D float array as CSV lines (ASCII, each ended by a newline), each number the shortest
    decimal that reads back as the same double (``1e-05`` may read ``0.00001``, ``1e+100`` ``1e100``);
    ``nan``, ``inf``, ``-inf`` as Python writes them.

    orjson formats a finite double by the same shortest-round-trip rule as ``repr``, many times faster
    (``benchmarks/bench_results_writing.py`` prints both), and the rows stay bytes from there to the file, so
    writing a run's results costs less than simulating it (issue 34). orjson writes a non-finite number as
    ``null``: such rows are formatted by ``repr``.
    """
    data = np.ascontiguousarray(data, dtype=np.float64)
    if data.ndim != 2:
        raise ValueError(f"data: must be a 2-D array, got shape {data.shape}")
    if data.shape[0] == 0:
        return b""
    if data.shape[1] == 0:
        return b"\n" * data.shape[0]
    text = orjson.dumps(data, option=orjson.OPT_SERIALIZE_NUMPY)[2:-2]  # [[1.5,2.0],[...]] without [[ and ]]
    bad = np.flatnonzero(~np.isfinite(data).all(axis=1))
    if bad.size == 0:
        return text.replace(b"],[", b"\n") + b"\n"
    rows = text.split(b"],[")
    for i in bad:
        rows[i] = ",".join(map(repr, data[i].tolist())).encode()
    return b"\n".join(rows) + b"\n"


def csv_rows(data: np.ndarray) -> list[str]:
    """The rows of :func:`csv_body` as strings, without their newlines."""
    body = csv_body(data).decode("ascii")
    return body.split("\n")[:-1] if body else []


def read_units(path: str | Path) -> dict[str, str]:
    """Column -> unit of a case CSV written by :func:`write_csv` (its first two lines)."""
    with open(path, encoding="utf-8") as f:
        names = f.readline().rstrip("\n").split(",")
        units = f.readline().rstrip("\n")
    if not units.startswith(UNITS_PREFIX):
        raise ValueError(f"{path}: no units line (a second line starting {UNITS_PREFIX!r})")
    return dict(zip(names, units[len(UNITS_PREFIX):].split(",")))


def analysis_columns(series: dict[str, np.ndarray], plant: str, reference) -> dict[str, np.ndarray]:
    """The reference, joint and error columns of a case's CSV.

    Parameters
    ----------
    series : dict
        ``time`` (s, shape (m,)) and the recorded ``<plant>.theta1..11``, ``<plant>.omega1..11``,
        ``<plant>.tip_x``, ``<plant>.tip_y``.
    plant : str
        The plant's instance name.
    reference : flexarm.reference.ReferenceSignals
        The reference (sample k = round(t / 1 ms), the final state held after t_f).

    Returns
    -------
    dict
        ``ref.<name>`` for every reference output; ``joint.q1, joint.q2, joint.qd1, joint.qd2`` of the plant's
        state; ``err.theta1..11``, ``err.omega1..11``, ``err.q1, err.q2, err.qd1, err.qd2``,
        ``err.tip_x``, ``err.tip_y`` = actual − reference. Each shape (m,).
    """
    from flexarm.model import joint_angles, joint_velocities
    from flexarm.reference import REFERENCE_OUTPUTS

    ref = np.array([reference.at_time(float(t)) for t in series["time"]])
    out = {f"ref.{name}": ref[:, j] for j, name in enumerate(REFERENCE_OUTPUTS)}
    theta = np.column_stack([series[f"{plant}.theta{i}"] for i in range(1, 12)])
    omega = np.column_stack([series[f"{plant}.omega{i}"] for i in range(1, 12)])
    q = np.array([joint_angles(th) for th in theta])
    qd = np.array([joint_velocities(om) for om in omega])
    joints = {"q1": q[:, 0], "q2": q[:, 1], "qd1": qd[:, 0], "qd2": qd[:, 1]}
    out.update({f"joint.{name}": v for name, v in joints.items()})
    for i in range(1, 12):
        out[f"err.theta{i}"] = theta[:, i - 1] - out[f"ref.theta_ref{i}"]
    for i in range(1, 12):
        out[f"err.omega{i}"] = omega[:, i - 1] - out[f"ref.omega_ref{i}"]
    for name, v in joints.items():
        out[f"err.{name}"] = v - out[f"ref.{name}_ref"]
    for axis in ("x", "y"):
        out[f"err.tip_{axis}"] = series[f"{plant}.tip_{axis}"] - out[f"ref.tip_{axis}_ref"]
    return out


def _npz_of(name: str) -> str:
    """Where a reference output comes from in flexarm/data/trajectory.npz (k = the sample, n = its last)."""
    m = re.fullmatch(r"(theta|omega)_ref(\d+)", name)
    if m:
        return f"`{m[1]}[k, {int(m[2]) - 1}]`"
    fixed = {"q1_ref": "`theta[k, 0]`", "q2_ref": "`theta[k, 6] - theta[k, 5]`", "qd1_ref": "`omega[k, 0]`",
             "qd2_ref": "`omega[k, 6] - omega[k, 5]`", "tau1_ff": "`tau[k, 0]` (k < n), 0",
             "tau2_ff": "`tau[k, 1]` (k < n), 0", "tip_x_ref": "`tip[k, 0]`", "tip_y_ref": "`tip[k, 1]`",
             "progress": "`k / n`"}
    return fixed.get(name, "")


def layout_table() -> str:
    """The markdown table of a case's CSV columns and, for the reference, the trajectory.npz entries."""
    rows = ["| CSV column | unit | meaning | trajectory.npz (sample k = round(t / 1 ms), capped at n) |",
            "|---|---|---|---|", "| `time` | s | communication point t_k | `t[k]` |"]
    for s in signals("plant", "output", ("state", "tip")):
        rows.append(f"| `plant.{s.name}` | {s.unit} | {s.description} (plant output) | |")
    for s in signals("controller", "output", indices=False):
        rows.append(f"| `controller.{s.name}` | {s.unit} | {s.description} (controller output) | |")
    for s in signals("sensors", "output", indices=False):
        rows.append(f"| `sensors.{s.name}` | {s.unit} | {s.description}: what the controller saw (when wired "
                    "into it) | |")
    rows.append("| `reference.<name>` | | a reference output wired into the controller (when it asks for it) | |")
    for s in signals("reference", "output"):
        rows.append(f"| `ref.{s.name}` | {s.unit} | {s.description} | {_npz_of(s.name)} |")
    for name, unit, meaning in JOINTS:
        rows.append(f"| `joint.{name}` | {unit} | the arm's {meaning} (from its state) | |")
    for s in signals("plant", "output", ("state", "tip")):
        ref = s.name.replace("theta", "theta_ref").replace("omega", "omega_ref") if "tip" not in s.name \
            else f"{s.name}_ref"
        rows.append(f"| `err.{s.name}` | {s.unit} | `plant.{s.name} - ref.{ref}` | |")
    for name, unit, _ in JOINTS:
        rows.append(f"| `err.{name}` | {unit} | `joint.{name} - ref.{name}_ref` | |")
    return "\n".join(rows)


def render_layout(text: str) -> str:
    """`text` with its generated layout block replaced by :func:`layout_table`."""
    block = re.compile(re.escape(_START) + r"\n.*?" + re.escape(_END), re.S)
    if not block.search(text):
        raise ValueError(f"no generated layout block ({_START}) in the text")
    return block.sub(lambda m: f"{_START}\n{layout_table()}\n{_END}", text)


def main() -> int:
    """Rewrite the generated layout table of :data:`LAYOUT_DOC`."""
    write_atomic(LAYOUT_DOC, render_layout(LAYOUT_DOC.read_text(encoding="utf-8")))
    print(f"wrote {LAYOUT_DOC}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
