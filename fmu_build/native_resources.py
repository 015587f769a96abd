"""Resource files of the native LQG controller FMU, written at build time from the committed LQG data.

Nothing here is copied by hand: the numbers come from :func:`flexarm.lqg.lqg_controller` (trajectory,
desired measurements as the law forms them) and :meth:`flexarm.lqg_design.LqgDesign.load` (which checks
the design files' data chain), written as IEEE-754 bit patterns (:func:`fmu_build.native_codegen.write_resource`),
exact on every platform. ``fmus/native/controller/controller_lqg.c`` reads them.

* ``lqg_trajectory.txt``: ``n_steps``, ``dt`` (s), ``feedforward_torque`` ((n_steps + 1) x 2, N·m),
  ``desired_measurements`` ((n_steps + 1) x 10: z_d C^T, the law's ``y_d``) and ``predictor_prior``
  (:data:`flexarm.lqg.PREDICTOR_PRIOR`).
* ``lqg_<schedule>.txt`` for each schedule (``200ms``, ``20ms``, ``single``): ``count``, ``times`` (s),
  ``Phi`` (count x 22 x 22), ``Gamma`` (count x 22 x 2), ``M`` (count x 22 x 10), ``C`` (10 x 22),
  ``K`` (count x 4 x 2 x 22) and ``K_integral`` (count x 4 x 2 x 24), the weights in the order of
  :data:`flexarm.gain_sets.WEIGHT_NAMES` (= the ``gain_set`` values 1..4), ``W`` (count x 22 x 22), ``V``
  (10 x 10) and ``P_prior0`` (22 x 22, the steady prior at the point of t = 0), all row-major.
* ``lqg_bank_<schedule>.txt`` for each schedule with a payload bank (:data:`flexarm.lqg_bank.BANK_SCHEDULES`,
  ``estimator = 2``), from :meth:`flexarm.lqg_bank.PayloadBank.load`: ``n_models``, ``n_filters``
  (= n_models + 1: the identification filters by mass, then the quiet filter), ``count``, ``schedule_period``
  (s), ``masses`` (kg), ``log_floor`` (log of :data:`flexarm.lqg_bank.POSTERIOR_FLOOR`, as the law computes it),
  ``reseed_below``, ``initial_log_p`` (the law's uniform start), ``times`` (s), and stacked over the filters
  ``C``, ``Phi``, ``Gamma``, ``M``, ``K``, ``K_integral`` (as above), ``S_inv`` (n_filters x count x 10 x 10),
  ``log_det_S`` (n_filters x count), ``psi`` (n_filters x count x 22 x 11) and ``delta_acceleration``
  (n_filters x (n_steps + 1) x 11); the C forms the drift ``psi[point of j] @ delta_acceleration[j]`` itself.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from flexarm.gain_schedule import default_trajectory_path
from flexarm.gain_sets import WEIGHT_NAMES
from flexarm.lqg import PREDICTOR_PRIOR, LqgController, lqg_controller
from flexarm.lqg_bank import BANK_SCHEDULES, POSTERIOR_FLOOR, QUIET_RESEED_BELOW, PayloadBank, bank_controller
from flexarm.lqg_design import DEFAULT_LQG_DIR, LqgDesign
from flexarm.parameters import load_parameters
from flexarm.provenance import sha256_file

from .native_codegen import GAIN_SETS, write_resource

TRAJECTORY_RESOURCE = "lqg_trajectory.txt"
#: The schedules, in the order of the C's SCHEDULE_LABELS (schedule_period 0.2, 0.02, 0).
SCHEDULES = ("200ms", "20ms", "single")
#: schedule_period (s) of each schedule (the FMU parameter's values).
SCHEDULE_PERIODS = {"200ms": 0.2, "20ms": 0.02, "single": 0.0}
#: The matrices of each bank filter's design in the bank resource (stacked over the filters).
BANK_DESIGN_ENTRIES = ("C", "Phi", "Gamma", "M", "K", "K_integral")


def design_resource(schedule: str) -> str:
    """File name of one schedule's design resource."""
    return f"lqg_{schedule}.txt"


def bank_resource(schedule: str) -> str:
    """File name of one schedule's payload-bank resource."""
    return f"lqg_bank_{schedule}.txt"


def write_bank_resource(path: Path, schedule: str, desired_measurements: np.ndarray) -> None:
    """The payload bank of `schedule` (:meth:`PayloadBank.load`) as the C reads it.

    `desired_measurements` is the trajectory resource's ``y_d``; the bank's law forms its own from its quiet
    filter's C, and the C reads the trajectory's: a bank whose sensor map or schedule differ is refused here.
    """
    bank = PayloadBank.load(schedule)
    filters = bank.models + [bank.quiet]
    law = bank_controller(schedule=schedule)
    times = filters[-1].design.times
    for b in filters:
        if not np.array_equal(b.design.times, times):
            raise RuntimeError(f"bank {schedule}: the filter of {b.mass} kg has other schedule times than the quiet "
                               "filter's (the C uses one schedule index)")
    if not np.array_equal(law.z @ law.design.C.T, desired_measurements):
        raise RuntimeError(f"bank {schedule}: its desired measurements z_d C^T differ from the trajectory "
                           "resource's (another sensor map)")
    n_models = len(bank.models)
    entries = {"n_models": [n_models], "n_filters": [len(filters)], "count": [len(times)],
               "schedule_period": [SCHEDULE_PERIODS[schedule]], "masses": bank.masses,
               "log_floor": [law.log_floor], "reseed_below": [law.reseed_below],
               "initial_log_p": law.initial_state().log_p, "times": times}
    entries.update({name: np.array([getattr(b.design, name) for b in filters]) for name in BANK_DESIGN_ENTRIES})
    entries.update({name: np.array([getattr(b, name) for b in filters])
                    for name in ("S_inv", "log_det_S", "psi", "delta_acceleration")})
    npz = DEFAULT_LQG_DIR / f"bank_{schedule}.npz"
    write_resource(path, entries,
                   f"flexarm LQG payload bank {schedule} (IEEE-754 hex bit patterns), fmu_build/native_resources.py\n"
                   f"source: {npz.name} sha256 {sha256_file(npz)}\n"
                   f"filters: payload masses {bank.masses.tolist()} kg, then the quiet filter; posterior floor "
                   f"{POSTERIOR_FLOOR:g}, quiet filter re-seeded below p_0 = {QUIET_RESEED_BELOW:g}")


def write_lqg_resources(directory: Path, bank: bool = True, data_dir: Path | None = None) -> list[Path]:
    """Write the trajectory, the three design and (with `bank`) the payload-bank resources into `directory`;
    returns their paths. `data_dir`: a payload data folder (:mod:`flexarm.payload_data`: its slew and LQG designs;
    it has no bank) instead of the committed data."""
    if [GAIN_SETS[v] for v in sorted(GAIN_SETS)] != list(WEIGHT_NAMES):
        raise RuntimeError(f"gain_set values {GAIN_SETS} are not in the order of the LQG weights {WEIGHT_NAMES}")
    if data_dir is not None and bank:
        raise RuntimeError(f"{data_dir}: a payload data folder has no payload bank")
    lqg_dir = DEFAULT_LQG_DIR if data_dir is None else Path(data_dir) / "lqg"
    traj_file = default_trajectory_path() if data_dir is None else Path(data_dir) / "trajectory.npz"
    # the law as the Python FMU's reads it: lqg_controller() on the committed data, the same on a folder's
    law = lqg_controller() if data_dir is None else LqgController(traj_file, LqgDesign.load("200ms", lqg_dir),
                                                                 "gamma0.1", 0, False, load_parameters().peak_torque)
    out = [directory / TRAJECTORY_RESOURCE]
    write_resource(out[0], {
        "n_steps": [law.n_steps], "dt": [law.dt], "feedforward_torque": law.trajectory.tau,
        "desired_measurements": law.z @ law.design.C.T,  # the law's y_d, the same expression
        "predictor_prior": [PREDICTOR_PRIOR],  # the paper's law predicting over a delay: its filter's prior
    }, "flexarm LQG controller: trajectory (IEEE-754 hex bit patterns), fmu_build/native_resources.py\n"
       f"source: {traj_file.name} sha256 {sha256_file(traj_file)}")
    for schedule in SCHEDULES:
        design = LqgDesign.load(schedule, lqg_dir)
        path = directory / design_resource(schedule)
        write_resource(path, {
            "count": [len(design.times)], "times": design.times, "Phi": design.Phi, "Gamma": design.Gamma,
            "M": design.M, "C": design.C, "K": design.K, "K_integral": design.K_integral,
            # the noise model of the predicting law's time-varying filter (flexarm.lqg_design.transient_gains)
            "W": design.W, "V": design.V, "P_prior0": design.P_prior[design.index_at(0.0)],
        }, f"flexarm LQG design {schedule} (IEEE-754 hex bit patterns), fmu_build/native_resources.py\n"
           f"source: lqg_{schedule}.npz sha256 {sha256_file(lqg_dir / f'lqg_{schedule}.npz')}\n"
           f"weights (gain_set 1..4): {', '.join(WEIGHT_NAMES)}")
        out.append(path)
    for schedule in BANK_SCHEDULES if bank else ():
        out.append(directory / bank_resource(schedule))
        write_bank_resource(out[-1], schedule, law.z @ law.design.C.T)
    return out
