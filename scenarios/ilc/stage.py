"""What an ILC trial tracks and learns against (:class:`Stage`): the paper's slew, or one re-planned for a payload that
is known (``[ilc] replan_payload_mass``) or identified from the first trial (``[ilc] identify_payload``).

A stage is the slew, its payload data folder (:mod:`flexarm.payload_data`; None for the paper's), the run plan with
that slew's desired states, the controller FMU the learning corrects (ours, or ours with the re-planned slew and its
gains packed in, :func:`fmu_build.learned.with_payload_data`), and the learning's model and law along the slew.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scenarios.config import ScenarioError
from scenarios.ilc.scenario import IlcSettings
from scenarios.run.setup import desired_states, start_parameters

#: Decimals (of a kg) of the payload a slew is re-planned for when the payload is identified.
PLANNED_DECIMALS = 3


@dataclass(frozen=True)
class Stage:
    """The slew a run's trials track at one point of the run, and everything that follows from it."""

    traj: object
    data: object  # flexarm.payload_data.PayloadData, or None for the paper's slew
    setup: object  # scenarios.run.setup.FmuSetPlan with this slew's desired states
    base: Path  # the controller FMU the learning corrects
    model: object  # flexarm.ilc.LtvModel
    law: object  # flexarm.ilc.NormOptimalIlc
    feedforward: np.ndarray
    n_slew: int

    @property
    def data_dir(self) -> Path | None:
        return None if self.data is None else self.data.folder

    def reference(self) -> dict:
        """Which slew this is, for the results (:func:`reference_record`)."""
        return reference_record(self.traj, self.data)


def reference_record(traj, data) -> dict:
    """Which slew the learning tracks and the metrics compare with: the paper's, or one re-planned for a payload."""
    if data is None:
        return {"slew": "committed", "description": "the paper's minimum-time slew of the unloaded arm "
                "(flexarm/data/trajectory.npz)", "t_f_s": float(traj.t_f)}
    return {"slew": "re-planned", "description": f"the minimum-time slew re-planned for {data.payload_mass:g} kg, "
            "with the gains designed along it (payload_data/)", "payload_mass_kg": data.payload_mass,
            "t_f_s": float(traj.t_f), "trajectory_sha256": data.manifest["files"]["trajectory.npz"]}


def gain_schedule(scenario) -> tuple[str, str]:
    """The gain set and schedule label the scenario's controller runs with (its defaults: gamma0.1, 200 ms)."""
    ctrl = scenario.parameters.get("controller", {})
    period = float(ctrl.get("schedule_period", 0.2))
    labels = {0.2: "200ms", 0.02: "20ms", 0.0: "single"}  # the controllers' schedule_period values
    if period not in labels:
        raise ScenarioError(f"{scenario.path.name}: parameters.controller.schedule_period: one of 0.2, 0.02 or 0 "
                            f"(s), got {period!r}")
    return ctrl.get("gain_set", "gamma0.1"), labels[period]


def learning_law(settings: IlcSettings, model, n_slew: int, time_weight, output_weight):
    """The learning law of the settings (:class:`flexarm.ilc.NormOptimalIlc`)."""
    from flexarm import ilc

    q = ({} if settings.settling_q_filter_cutoff_hz == settings.q_filter_cutoff_hz else
         {"settling_q_cutoff_hz": settings.settling_q_filter_cutoff_hz, "settling_start": n_slew})
    return ilc.NormOptimalIlc(model, settings.error_weight, settings.input_weight, settings.q_filter_cutoff_hz,
                              settings.q_filter_order, settings.leak_weight, time_weight=time_weight,
                              learning_gain=settings.learning_gain, output_weight=output_weight, **q)


def make_stage(settings: IlcSettings, setup, traj, data, controller: Path, fmu_dir: Path,
               python_twin: Path | None = None) -> Stage:
    """The stage of slew `traj` (re-planned into the payload data `data`, or the paper's with None).

    `setup` is the run's plan (its desired states and start are replaced by the slew's), `controller` our controller
    FMU the run resolved, `fmu_dir` where the stage's own controller FMU (with the payload data) is written. A native
    controller is built anew on the data (`python_twin`: its Python twin, the interface); a Python one gets the data
    packed into a copy.
    """
    from flexarm import ilc
    from fmu_build.learned import native_with_payload_data, with_payload_data

    scenario, n = setup.scenario, setup.n_steps
    setup = dataclasses.replace(setup, desired=desired_states(traj, np.arange(n + 1) * scenario.step_size),
                                start=start_parameters(traj), trajectory=traj)
    n_slew = min(traj.n_samples, n)
    along = {} if data is None else {"trajectory": traj, "gains": data.gains(*gain_schedule(scenario))}
    # on a re-planned slew the learning's model is the arm with the payload it was re-planned for
    payload = settings.model_payload_mass if data is None else data.payload_mass
    settling_payload = settings.settling_model_payload_mass if data is None else data.payload_mass
    model = ilc.closed_loop_model(n, payload_mass=payload, **along)
    if settling_payload != payload:
        # the samples at and after t_f (state x_k, k >= n_slew) move by the arm with the other payload
        after = ilc.closed_loop_model(n, payload_mass=settling_payload, **along)
        model = ilc.spliced_model(model, after, n_slew)
    time_weight, output_weight = ilc.settling_weights(traj, n, settings.settling_weight, settings.settling_tip_weight)
    own = Path(fmu_dir) / f"payload_{controller.name}"
    if data is None:
        base = controller
    elif setup.kind == "native":
        base = native_with_payload_data(controller.stem, python_twin, data, own)
    else:
        base = with_payload_data(controller, data, own)
    return Stage(traj, data, setup, base, model, learning_law(settings, model, n_slew, time_weight, output_weight),
                 ilc.feedforward_over(traj, n), n_slew)


def identified_payload(res: dict, stage: Stage, sensors: str) -> dict:
    """The payload identified from a trial's encoder measurements and the torques applied
    (:func:`flexarm.payload_fit.identify_payload`), as the record a trial's journal line carries, with the payload
    the slew is re-planned for (``planned_for_kg``: to :data:`PLANNED_DECIMALS` decimals).

    Raises
    ------
    ScenarioError
        A stepping other than Gauss-Seidel (the fit takes the measurement of sample k as the state at t_k), or a
        trial that does not identify the payload.
    """
    from flexarm.payload_fit import IdentificationError, identify_payload

    setup = stage.setup
    if setup.scenario.algorithm != "gauss-seidel":
        raise ScenarioError(f"{setup.scenario.path.name}: ilc.identify_payload: a Gauss-Seidel scenario (the fit reads "
                            f"the measurement of sample k as the state at t_k), got {setup.scenario.algorithm!r}")
    sig = res["signals"]
    q = np.column_stack([sig[f"{sensors}.q1_m"], sig[f"{sensors}.q2_m"]])
    tau = np.column_stack([sig[f"{setup.driver}.tau1"], sig[f"{setup.driver}.tau2"]])[:-1]  # the last: never applied
    try:
        estimate = identify_payload(q, tau, stage.traj.state(0)).as_dict()
    except IdentificationError as exc:
        raise ScenarioError(f"{setup.scenario.path.name}: ilc.identify_payload: {exc}") from exc
    # the slew is re-planned for the payload to the gram: a gram moves t_f by about 0.1 ms, less than a sample
    return dict(estimate, planned_for_kg=round(estimate["payload_mass_kg"], PLANNED_DECIMALS))
