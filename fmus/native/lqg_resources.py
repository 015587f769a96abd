"""Resource files of the native LQG controller FMU, written at build time from the committed LQG data.

Nothing here is copied by hand: the numbers come from :func:`flexarm.lqg.lqg_controller` (trajectory,
desired measurements as the law forms them) and :meth:`flexarm.lqg_design.LqgDesign.load` (which checks
the design files' data chain), written as IEEE-754 bit patterns (:func:`physics_codegen.write_resource`),
exact on every platform. ``fmus/native/controller/controller_lqg.c`` reads them.

* ``lqg_trajectory.txt``: ``n_steps``, ``dt`` (s), ``feedforward_torque`` ((n_steps + 1) x 2, N·m) and
  ``desired_measurements`` ((n_steps + 1) x 10: z_d C^T, the law's ``y_d``).
* ``lqg_<schedule>.txt`` for each schedule (``200ms``, ``20ms``, ``single``): ``count``, ``times`` (s),
  ``Phi`` (count x 22 x 22), ``Gamma`` (count x 22 x 2), ``M`` (count x 22 x 10), ``C`` (10 x 22),
  ``K`` (count x 4 x 2 x 22) and ``K_integral`` (count x 4 x 2 x 24), the weights in the order of
  :data:`flexarm.gain_sets.WEIGHT_NAMES` (= the ``gain_set`` values 1..4), all row-major.
"""

from __future__ import annotations

from pathlib import Path

from flexarm.gain_schedule import default_trajectory_path
from flexarm.gain_sets import WEIGHT_NAMES
from flexarm.lqg import lqg_controller
from flexarm.lqg_design import DEFAULT_LQG_DIR, LqgDesign
from flexarm.provenance import sha256_file

from .physics_codegen import GAIN_SETS, write_resource

TRAJECTORY_RESOURCE = "lqg_trajectory.txt"
#: The schedules, in the order of the C's SCHEDULE_LABELS (schedule_period 0.2, 0.02, 0).
SCHEDULES = ("200ms", "20ms", "single")


def design_resource(schedule: str) -> str:
    """File name of one schedule's design resource."""
    return f"lqg_{schedule}.txt"


def write_lqg_resources(directory: Path) -> list[Path]:
    """Write the trajectory and the three design resources into `directory`; returns their paths."""
    if [GAIN_SETS[v] for v in sorted(GAIN_SETS)] != list(WEIGHT_NAMES):
        raise RuntimeError(f"gain_set values {GAIN_SETS} are not in the order of the LQG weights {WEIGHT_NAMES}")
    law = lqg_controller()  # the committed trajectory, as the Python FMU's law reads it
    traj_file = default_trajectory_path()
    out = [directory / TRAJECTORY_RESOURCE]
    write_resource(out[0], {
        "n_steps": [law.n_steps], "dt": [law.dt], "feedforward_torque": law.trajectory.tau,
        "desired_measurements": law.z @ law.design.C.T,  # the law's y_d, the same expression
    }, "flexarm LQG controller: trajectory (IEEE-754 hex bit patterns), fmus/native/lqg_resources.py\n"
       f"source: {traj_file.name} sha256 {sha256_file(traj_file)}")
    for schedule in SCHEDULES:
        design = LqgDesign.load(schedule)
        path = directory / design_resource(schedule)
        write_resource(path, {
            "count": [len(design.times)], "times": design.times, "Phi": design.Phi, "Gamma": design.Gamma,
            "M": design.M, "C": design.C, "K": design.K, "K_integral": design.K_integral,
        }, f"flexarm LQG design {schedule} (IEEE-754 hex bit patterns), fmus/native/lqg_resources.py\n"
           f"source: lqg_{schedule}.npz sha256 {sha256_file(DEFAULT_LQG_DIR / f'lqg_{schedule}.npz')}\n"
           f"weights (gain_set 1..4): {', '.join(WEIGHT_NAMES)}")
        out.append(path)
    return out
