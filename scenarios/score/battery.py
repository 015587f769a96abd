"""The score's battery (issue 36): a fixed, versioned set of runs, and one run of it.

The battery's cases all use Table 2's set-up (``scenarios/table2.toml``: plant, sensors, the reference FMU, 1 ms
steps) with the scored controller swapped in, each run for the slew plus :data:`SETTLE_S`:

* ``paper``: the paper's four cases of Tables 1-3 (no payload or the 0.275 kg tip mass, the paper's model
  error; sensor noise off or on). Tables 1-3 differ only in the LQR's weight, a setting of our controller, so
  for any other controller they are the same four runs, under Gauss-Seidel and Jacobi stepping;
* ``robust``: payload 0-0.5 kg in 0.1 kg steps x noise seeds 1-3 (noise on), Gauss-Seidel.

The six table metrics are taken over the slew (the samples of a ``run`` of Table 2, so they equal its figures);
the verdict (:mod:`scenarios.run.verdict`) over the whole run, and the settling time after t_f from the rest.
A change of the cases is a new :data:`BATTERY_VERSION`; the baseline file records the battery it was made with.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import asdict, dataclass, field

import numpy as np

#: Bump whenever a case, the run length or a baseline controller's settings change.
BATTERY_VERSION = 1
#: Seconds run after the slew, for the settling time (the settling scenario's tip settles to 1 mm in about 1 s).
SETTLE_S = 1.5
#: The tip has settled once it stays within this distance of the slew's end point, m.
SETTLE_TOL_M = 1e-3
#: The loop delay a Jacobi master at 1 ms puts between the plant state and the torques (sensors, then controller),
#: told to a controller that declares ``loop_delay_samples`` (docs/own-controller.md, "Jacobi masters").
JACOBI_LOOP_DELAY = 2
PAYLOADS = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5)
SEEDS = (1, 2, 3)
STEPPINGS = ("gauss-seidel", "jacobi")


@dataclass(frozen=True)
class Case:
    """One run of the battery."""

    key: str
    group: str  # "paper" or "robust"
    label: str
    algorithm: str
    payload_kg: float
    noise: bool
    seed: int = 1

    def parameters(self) -> dict[str, dict]:
        return {"plant": {"payload_mass": self.payload_kg},
                "sensors": {"noise_enabled": self.noise, "noise_seed": self.seed}}


def cases() -> list[Case]:
    """The battery, in the order of the page."""
    out = []
    for alg in STEPPINGS:
        short = "gs" if alg == "gauss-seidel" else "jacobi"
        for key, label, payload, noise in (("none", "no tip mass, no noise", 0.0, False),
                                           ("noise", "no tip mass, with noise", 0.0, True),
                                           ("tip", "0.275 kg tip mass, no noise", 0.275, False),
                                           ("tip_noise", "0.275 kg tip mass, with noise", 0.275, True)):
            out.append(Case(f"{key}_{short}", "paper", f"{label} ({alg})", alg, payload, noise))
    for payload in PAYLOADS:
        for seed in SEEDS:
            out.append(Case(f"m{payload:.1f}_s{seed}", "robust", f"{payload:.1f} kg, noise seed {seed}",
                            "gauss-seidel", payload, True, seed))
    return out


@dataclass(frozen=True)
class Controller:
    """A scored controller: one of our FMU names with its settings, or a .fmu path (a user's)."""

    name: str  # what the page calls it
    fmu: str  # an FMU name of this project or a .fmu path
    parameters: dict = field(default_factory=dict)
    #: Settings added under Jacobi stepping (our LQG's loop delay).
    jacobi_parameters: dict = field(default_factory=dict)


#: Our baselines, as the page shows them beside the scored controller. The learned controller (ILC) needs a
#: learned-feedforward file that an ILC run writes (none is committed), so it is not in the battery.
BASELINES = (
    Controller("lqr", "controller", {"gain_set": "gamma0.1", "schedule_period": 0.2}),
    Controller("dlqr", "controller_dlqr", {"gain_set": "gamma0.1", "schedule_period": 0.2}),
    Controller("lqg_bank", "controller_lqg", {"gain_set": "gamma0.1", "schedule_period": 0.2,
                                              "estimator": "payload_bank"},
               {"loop_delay_samples": JACOBI_LOOP_DELAY}),
)


def named(name: str) -> Controller:
    """A baseline by its page name (lqr, dlqr, lqg_bank); ValueError listing them."""
    for c in BASELINES:
        if c.name == name:
            return c
    raise ValueError(f"controller: one of our baselines {[c.name for c in BASELINES]} or a path to a .fmu, "
                     f"got {name!r}")


def battery_sha256() -> str:
    """SHA-256 of the battery's definition (cases, run length, settling rule, baselines' settings)."""
    doc = {"version": BATTERY_VERSION, "settle_s": SETTLE_S, "settle_tol_m": SETTLE_TOL_M,
           "cases": [asdict(c) for c in cases()], "baselines": [asdict(c) for c in BASELINES]}
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()


# ---------------------------------------------------------------------------------------------- one run


def settle_time(time, tip, end, t_f: float, tol: float = SETTLE_TOL_M) -> float | None:
    """Seconds after t_f until the tip stays within `tol` of `end` for the rest of the run; None if it does not
    by the run's end (or the run ends before t_f)."""
    t = np.asarray(time)
    dist = np.linalg.norm(np.asarray(tip) - np.asarray(end), axis=1)
    after = t >= t_f - 1e-9
    if not after.any():
        return None
    outside = np.flatnonzero(after & (dist > tol))
    if not outside.size:
        return 0.0
    k = outside[-1] + 1
    return None if k >= len(t) else float(max(t[k] - t_f, 0.0))


#: Per process: (controller, kind, algorithm, fmu dirs) -> (Setup, Master), loaded once (a Dask worker keeps them).
_LOADED: dict = {}


def _loaded(controller: Controller, kind: str, algorithm: str, fmu_dir: str, native_fmu_dir: str):
    from dataclasses import replace
    from pathlib import Path

    from scenarios.run.setup import prepare

    from ..config import load_scenario

    key = (controller.fmu, kind, algorithm, fmu_dir, native_fmu_dir)
    if key not in _LOADED:
        scenario = load_scenario("table2")
        from flexarm.trajectory import load_trajectory

        traj = load_trajectory()
        scenario = replace(scenario, samples=math.ceil(traj.t_f / scenario.step_size - 1e-9)
                           + round(SETTLE_S / scenario.step_size))
        setup = prepare(scenario, Path(fmu_dir), controller.fmu, build=False, kind=kind,
                        native_fmu_dir=Path(native_fmu_dir), algorithm=algorithm, trajectory=traj)
        _LOADED[key] = (setup, setup.open_master(algorithm))
    return _LOADED[key]


def run_case(case: Case, controller: Controller, kind: str, fmu_dir: str, native_fmu_dir: str,
             keep_series: bool = False) -> dict:
    """One battery run: status, verdict, the slew's six metrics, the settling time (and, with `keep_series`,
    the series the page's figures draw, every 5th sample)."""
    from flexarm.parameters import load_parameters
    from scenarios.run.plan import plan_case
    from scenarios.run.runner import simulate
    from scenarios.run.verdict import series_verdict

    from ..metrics import table_metrics
    from ..results import analysis_columns

    setup, m = _loaded(controller, kind, case.algorithm, fmu_dir, native_fmu_dir)
    params = case.parameters()
    ctrl = {**controller.parameters, **(controller.jacobi_parameters if case.algorithm == "jacobi" else {})}
    if (controller.fmu.endswith(".fmu") and case.algorithm == "jacobi" and "loop_delay_samples" not in ctrl
            and _declares(setup, "loop_delay_samples")):  # the documented name (docs/own-controller.md); a --set wins
        ctrl["loop_delay_samples"] = JACOBI_LOOP_DELAY
    if ctrl:
        params["controller"] = ctrl
    out, _ = simulate(setup, m, plan_case(setup, case.key, case.key, params).parameters)
    rec = {"case": case.key, "status": out["status"], "message": out["message"], "verdict": None,
           "growth_rate_per_s": None, "metrics": None, "settle_s": None}
    if out["status"] != "ok":
        return rec
    traj = setup.trajectory  # the FMU set's, loaded once per process
    series = {"time": out["time"], **out["signals"]}
    series.update(analysis_columns(series, setup.plant, _reference(traj)))
    judged = series_verdict(series, setup.driver, load_parameters().peak_torque)
    n = math.ceil(traj.t_f / setup.scenario.step_size - 1e-9) + 1  # the samples of a run of Table 2
    p, d = setup.plant, setup.driver
    theta = np.column_stack([series[f"{p}.theta{i}"] for i in range(1, 12)])[:n]
    omega = np.column_stack([series[f"{p}.omega{i}"] for i in range(1, 12)])[:n]
    tau = np.column_stack([series[f"{d}.tau1"], series[f"{d}.tau2"]])[:n]
    desired = setup.desired
    tip = np.column_stack([series[f"{p}.tip_x"], series[f"{p}.tip_y"]])
    rec.update(status="ok" if judged["verdict"] == "stable" else judged["verdict"], message=judged["message"],
               verdict=judged["verdict"],
               growth_rate_per_s=judged["growth"]["growth_rate_per_s"] if judged["growth"] else None,
               onset_s=judged["growth"]["onset_s"] if judged["growth"] else None,
               saturated_share=judged["saturated_share"],
               metrics=table_metrics(tau, theta, omega, desired["theta"][:n], desired["omega"][:n]),
               settle_s=settle_time(series["time"], tip, traj.tip[-1], traj.t_f))
    if keep_series:
        k = slice(None, None, 5)
        rec["series"] = {"time": series["time"][k].tolist(),
                         "velocity_error": np.degrees(np.abs(np.column_stack(
                             [series[f"err.omega{i}"] for i in range(1, 12)])).max(axis=1))[k].tolist(),
                         "position_error": np.degrees(np.abs(np.column_stack(
                             [series[f"err.theta{i}"] for i in range(1, 12)])).max(axis=1))[k].tolist(),
                         "tau1": series[f"{d}.tau1"][k].tolist(), "tau2": series[f"{d}.tau2"][k].tolist(),
                         "tip_x": tip[k, 0].tolist(), "tip_y": tip[k, 1].tolist()}
    return rec


def _reference(traj):
    """The reference signals of the trajectory `traj` (made once per process)."""
    if "reference" not in _LOADED_REF:
        from flexarm.reference import ReferenceSignals

        _LOADED_REF["reference"] = ReferenceSignals(traj)
    return _LOADED_REF["reference"]


_LOADED_REF: dict = {}


def _declares(setup, name: str) -> bool:
    md = setup.descriptions.get("controller")
    return md is not None and any(v.name == name for v in md.modelVariables)


def close_all() -> None:
    """Free every loaded master of this process."""
    while _LOADED:
        _, (_, m) = _LOADED.popitem()
        m.close()
