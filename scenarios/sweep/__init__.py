"""Sweeps and Monte Carlo over a scenario, run on Dask (or in-process).

A sweep file (TOML; shipped ones in ``scenarios/sweeps/``) names a base
scenario, one of its cases as the base point, and the axes to vary::

    [sweep]
    name = "robustness"
    scenario = "table2"            # a scenario name in scenarios/, or a path relative to this file
    case = "noise"                 # the base point (default: the scenario's first case)
    samples = 200                  # optional: override the run length (communication steps)

    [axes]
    plant.payload_mass = [0.0, 0.1, 0.2]                          # grid values
    controller.gain_set = ["gamma0", "gamma0.1"]                  # grid values (strings, booleans too)
    sensors.noise_seed = { range = [1, 20] }                      # integers 1..20 (optional step)
    fmus.controller = ["controller", "controller_fb"]             # FMU swap
    # or random samples: plant.payload_mass = { uniform = [0.0, 0.5], count = 50, seed = 7 }

Every point of the cartesian product of the axes (in file order, the last
axis fastest) is one co-simulation. Each result is appended, as it arrives,
to a JSON-lines journal in the output folder (flushed and fsynced per point;
key: a hash of what defines the point's run -- the parsed scenario, the run
length, the FMU names and the parameters -- so a comment in the sweep or
scenario file, or a new value on an axis, reruns nothing already run); a
rerun skips the points the journal holds as ``ok`` or ``unbounded`` and
reruns ``error`` ones and those a Ctrl-C interrupted (never journaled).
The table (CSV, and Parquet when pyarrow is importable) is written
atomically from the journal.

Before any point runs, every value is checked against the FMUs' model
descriptions (type, range, enumeration items: a choice name such as
``"gamma0.1"`` is mapped to its integer) and the base point is initialised
and stepped once on each FMU set, so a refusal names the field or quotes
the FMU before anything runs.

Statuses (docs/outcomes.md): ``ok``; ``unbounded`` (a recorded signal left
the bounds: when and which; metrics empty); ``error`` (an FMU returned
fmi2Error or worse: which FMU, function, status and its message; or an
exception, or the worker died).

Modules: :mod:`.spec` (the file), :mod:`.plan` (FMU checks, points),
:mod:`.worker` (running points, Dask), :mod:`.journal` (journal, table),
:mod:`.report` (progress, summary, plots), :mod:`.run` (:func:`run_sweep`, CLI).

Execution: a :class:`distributed.LocalCluster` (one process per core, one
thread each: the FMUs run Python and share the GIL), an existing Dask
cluster (``scheduler="tcp://host:8786"``), or in-process (``serial=True``).
The client reads the FMU files once and a worker plugin (:class:`ShipFmus`)
writes their bytes into a content-addressed folder on every worker (also
on workers that join or restart later); each process keeps one loaded
:class:`~scenarios.master.cosim.Master` per FMU set (reset between runs by
``fmi2Reset``). So remote workers need the project installed (same
version) but no FMU files of their own, and the SHA-256 recorded with a
point is that of the bytes that ran it.
"""


# The names are loaded on first use (PEP 562): importing one module of the package, such as .journal for an
# ILC campaign, must not import Dask (.worker), which costs most of a second.
_HOME = {
    "DONE": "journal",
    "STATUSES": "journal",
    "Journal": "journal",
    "read_table": "journal",
    "table_columns": "journal",
    "table_rows": "journal",
    "write_table": "journal",
    "FmuSet": "plan",
    "Plan": "plan",
    "Point": "plan",
    "plan_sweep": "plan",
    "point_key": "plan",
    "Progress": "report",
    "format_summary": "report",
    "summary_plots": "report",
    "DEFAULT_OUT_DIR": "run",
    "SweepResult": "run",
    "cli": "run",
    "run_sweep": "run",
    "MAX_POINTS": "spec",
    "SWEEP_DIR": "spec",
    "Axis": "spec",
    "Sweep": "spec",
    "SweepError": "spec",
    "load_sweep": "spec",
    "sweep_path": "spec",
    "ShipFmus": "worker",
    "close_loaded": "worker",
    "iter_dask": "worker",
    "iter_serial": "worker",
    "local_cluster": "worker",
    "run_point": "worker",
    "store_fmus": "worker",
}

__all__ = ["DONE", "STATUSES", "Journal", "read_table", "table_columns", "table_rows", "write_table", "FmuSet",
           "Plan", "Point", "plan_sweep", "point_key", "Progress", "format_summary", "summary_plots",
           "DEFAULT_OUT_DIR", "SweepResult", "cli", "run_sweep", "MAX_POINTS", "SWEEP_DIR", "Axis", "Sweep",
           "SweepError", "load_sweep", "sweep_path", "ShipFmus", "close_loaded", "iter_dask", "iter_serial",
           "local_cluster", "run_point", "store_fmus"]

def __getattr__(name: str):
    if name not in _HOME:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib

    return getattr(importlib.import_module(f".{_HOME[name]}", __name__), name)


def __dir__() -> list[str]:
    return sorted(list(globals()) + list(_HOME))

