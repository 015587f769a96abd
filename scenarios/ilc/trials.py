"""Iterative learning control through the FMUs: a scenario kind that repeats a case and learns between trials.

A scenario file with an ``[ilc]`` table (``scenarios/ilc_payload.toml``) runs with
``python -m scenarios run NAME`` (the command line hands such files here, :func:`is_ilc_scenario`):

1. trial j = 0, 1, ..., ``trials`` − 1 of the ``learn_case`` runs the FMUs (plant at rest on the trajectory's
   start, as every run; the sensors' ``noise_seed`` = ``seed_base`` + j) with a copy of the controller FMU that
   carries the correction learnt so far in its resources (none in trial 0; ``fmu_build.learned``);
2. from the *recorded sensor measurements* of the trial (encoders ``q1_m``, ``q2_m`` and strain gauges
   ``eps1_m`` .. ``eps6_m``; never the plant's states) :mod:`flexarm.ilc` computes the next correction, which
   is written as a learned-feedforward design file with its provenance;
3. a line per trial is printed and appended to ``journal.jsonl`` (fsynced): an interrupted run resumes after
   its last finished trial, with the correction that trial produced. A journal written with another scenario
   file, other FMUs or another commit's ILC settings is refused rather than mixed;
4. after the last trial the ``evaluate_cases`` run without and with the final correction (a payload change);
   ``trials.csv``, ``evaluation.json``, ``convergence.png``, ``learned_feedforward.npz``/``.json`` and
   ``learned_controller.fmu`` (the controller FMU with the final correction inside it: it runs in any FMI tool,
   no file or String parameter to set) are written.

The plant's true states are read only to score the trials (the metrics of the paper's tables over the slew,
and the tip's distance to the end point), exactly as the other scenarios score theirs.
"""

from __future__ import annotations

import dataclasses
import shutil
import sys
import time
from pathlib import Path

import numpy as np

from flexarm.provenance import git_commit, sha256_file, write_atomic, write_json
from scenarios.config import ScenarioError
from scenarios.ilc.scenario import load_ilc
from scenarios.ilc.stage import identified_payload, make_stage
from scenarios.ilc.trial_table import plot_convergence, trial_header, trial_line, write_trials_csv
from scenarios.metrics import table_metrics
from scenarios.results import portable
from scenarios.run.fmus import DEFAULT_FMU_DIR, DEFAULT_NATIVE_FMU_DIR, fmu_kind
from scenarios.run.outdir import check_writable, folder_lock, remove_stale
from scenarios.run.runner import N_EL
from scenarios.run.setup import checkout_relative, desired_states, prepare, verified_data
from scenarios.sweep.journal import Journal

#: The measurements the learning reads (sensors FMU outputs): encoders, then strain gauges.
MEASURED = ("q1_m", "q2_m", "eps1_m", "eps2_m", "eps3_m", "eps4_m", "eps5_m", "eps6_m")
#: Tip distance to the end point that counts as arrived, m.
TIP_TOLERANCE_M = 1e-3
#: In an ILC result folder: the controller FMU with the final correction inside it.
LEARNED_CONTROLLER = "learned_controller.fmu"


# -- scoring ----------------------------------------------------------------------------
def trial_metrics(out: dict, setup, traj, n_slew: int, measured_error_norm: float, desired=None) -> dict:
    """The table metrics over the slew (samples 0..n_slew, as Table 2) and the whole run, joint and tip errors,
    the tip's settling after t_f (the time after which it stays within 1 mm of the end point to the end of the
    run), the peak torques and the 2-norm of the measured error the learning saw. `desired`: the desired states
    of a run longer than ``setup``'s (default ``setup.desired``)."""
    sig, p, d = out["signals"], setup.plant, setup.driver
    theta = np.column_stack([sig[f"{p}.theta{i}"] for i in range(1, N_EL + 1)])
    omega = np.column_stack([sig[f"{p}.omega{i}"] for i in range(1, N_EL + 1)])
    tau = np.column_stack([sig[f"{d}.tau1"], sig[f"{d}.tau2"]])[:-1]  # the last row is never applied
    des = setup.desired if desired is None else desired
    slew = table_metrics(tau[:n_slew], theta[:n_slew + 1], omega[:n_slew + 1], des["theta"][:n_slew + 1],
                         des["omega"][:n_slew + 1])
    whole = table_metrics(tau, theta, omega, des["theta"], des["omega"])
    from flexarm import joint_angles

    q = np.array([joint_angles(th) for th in theta])
    q_d = np.array([joint_angles(th) for th in des["theta"]])
    qe = np.degrees(q - q_d)
    tip = np.column_stack([sig[f"{p}.tip_x"], sig[f"{p}.tip_y"]])
    idx = np.minimum(np.arange(len(tip)), traj.n_samples)
    tip_err = np.linalg.norm(tip - traj.tip[idx], axis=1)
    to_end = np.linalg.norm(tip - traj.tip[-1], axis=1)
    far = np.flatnonzero(to_end >= TIP_TOLERANCE_M)
    t_in = out["time"][far[-1] + 1] if len(far) and far[-1] + 1 < len(tip) else (0.0 if not len(far) else None)
    from flexarm.control import PEAK_TORQUE

    limits = np.array(PEAK_TORQUE)
    return {
        **{f"slew_{k}": v for k, v in slew.items()},
        **{f"run_{k}": v for k, v in whole.items()},
        "rms_q1_error_deg": float(np.sqrt(np.mean(qe[:n_slew + 1, 0] ** 2))),
        "rms_q2_error_deg": float(np.sqrt(np.mean(qe[:n_slew + 1, 1] ** 2))),
        "peak_q1_error_deg": float(np.abs(qe[:, 0]).max()), "peak_q2_error_deg": float(np.abs(qe[:, 1]).max()),
        "rms_tip_error_mm": float(1e3 * np.sqrt(np.mean(tip_err[:n_slew + 1] ** 2))),
        "peak_tip_error_mm": float(1e3 * tip_err.max()),
        "tip_within_1mm_after_tf_s": None if t_in is None else float(max(t_in - traj.t_f, 0.0)),
        "tip_to_end_at_tf_plus_0.5s_mm": float(1e3 * to_end[min(n_slew + 500, len(to_end) - 1)]),
        "saturated_samples": int(np.sum(np.abs(tau) >= limits - 1e-9)),
        "measured_error_2norm_rad": float(measured_error_norm),
    }


# -- running ----------------------------------------------------------------------------
def _config_record(scenario, settings, setup, chain, data) -> dict:
    return {"key": "config", "scenario_sha256": sha256_file(scenario.path), "settings": settings.as_dict(),
            "fmu_sha256": {i: sha256_file(p) for i, p in setup.paths.items()}, "data_sha256": chain,
            "payload_data_sha256": data.manifest["files"] if data else None,
            "samples": setup.n_steps, "fmu_kind": setup.kind}


def run_ilc(name, out_dir: Path, fmu_dir: Path = DEFAULT_FMU_DIR, kind: str | None = None,
            native_fmu_dir: Path = DEFAULT_NATIVE_FMU_DIR, plots: bool = True, progress=print,
            trials: int | None = None) -> dict:
    """Run (or resume) an ILC scenario; returns the summary written to ``evaluation.json``.

    `trials` overrides the file's number of trials (e.g. a short check). Raises :class:`ScenarioError` for
    refused input, :class:`scenarios.run.outdir.OutputError` for an unusable folder; a trial that ends unbounded
    or with an FMU error stops the learning (the journal keeps it) and is reported in the summary's ``stopped``.
    """
    from flexarm.payload_data import write_payload_data

    scenario, settings = load_ilc(name)
    if trials is not None:
        settings.trials = int(trials)
    chain, traj = verified_data()  # the trajectory loaded once, with the data chain
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    folder = out / scenario.name
    with folder_lock(out, scenario.name):
        remove_stale(out, scenario.name, folder)
        check_writable(folder, 2_000_000 * (settings.trials + 2))
        setup = prepare(scenario, fmu_dir, kind=kind, native_fmu_dir=native_fmu_dir, trajectory=traj)
        sensor, ctrl, twin = _learning_instances(scenario, settings, setup, fmu_dir)
        data = None  # the slew re-planned for a known payload (flexarm.payload_data); None: the paper's, at first
        if settings.replan_payload_mass is not None:
            data = write_payload_data(settings.replan_payload_mass, folder / "payload_data", progress)
        journal, rows = _open_journal(folder, _config_record(scenario, settings, setup, chain, data), settings)
        # identify_payload: trial 0 runs on the paper's slew, the payload is identified from it, the slew re-planned
        # for it, and the learning starts on that slew with trial 1 (no correction carried across slews)
        first = 1 if settings.identify_payload else 0  # the first trial the learning learns from
        if first and rows and rows[0].get("identified"):
            data = write_payload_data(rows[0]["identified"]["planned_for_kg"], folder / "payload_data", progress)
        run = _Learning(scenario, settings, setup, sensor, ctrl, twin, folder, chain, first, progress)
        run.stage = make_stage(settings, setup, traj if data is None else data.trajectory(), data, setup.paths[ctrl],
                               run.trial_fmus, twin)
        try:
            stopped = run.trials(rows, journal)
            evaluation = run.evaluate(len(rows)) if stopped is None else {}
        finally:
            journal.close()
            run.close()
        summary = {"scenario": scenario.name, "scenario_sha256": sha256_file(scenario.path), "commit": run.commit,
                   "settings": settings.as_dict(), "fmu_kind": setup.kind, "reference": run.stage.reference(),
                   "fmu_sha256": {i: sha256_file(p) for i, p in setup.paths.items()}, "data_sha256": chain,
                   "samples": setup.n_steps, "slew_samples": run.stage.n_slew, "trials": rows, "stopped": stopped,
                   "evaluation": evaluation}
        if first and rows and rows[0].get("identified"):
            summary["identified"] = rows[0]["identified"]
        if evaluation:
            summary["learned_controller"] = {"file": LEARNED_CONTROLLER, "instance": ctrl,
                                             "sha256": sha256_file(folder / LEARNED_CONTROLLER)}
        write_json(folder / "evaluation.json", portable(summary, folder))
        write_trials_csv(folder / "trials.csv", rows)
        if plots and rows:
            plot_convergence(rows, folder / "convergence.png", scenario.name)
    return summary


def _learning_instances(scenario, settings, setup, fmu_dir: Path) -> tuple[str, str, Path]:
    """(the sensors instance, the controller instance, a native controller's Python twin); ScenarioError for a set
    of FMUs the learning cannot run on."""
    from fmu_build.learned import LEARNING_CONTROLLERS, reads_learned_feedforward
    from fmu_build.native_build import PAYLOAD_DATA_VARIANTS

    sensors = [inst for inst, md in setup.descriptions.items()
               if all(any(v.name == m for v in md.modelVariables) for m in MEASURED)]
    ctrl = setup.driver
    if not sensors:
        raise ScenarioError(f"{scenario.path.name}: no FMU outputs the measurements {list(MEASURED)}")
    md = setup.descriptions[ctrl]
    if fmu_kind(md) == "other" or not reads_learned_feedforward(md.coSimulation.modelIdentifier):
        raise ScenarioError(f"fmus.{ctrl}: {setup.paths[ctrl].name} does not read a learned feedforward; ILC "
                            "runs need one of our controllers that does "
                            f"({', '.join(LEARNING_CONTROLLERS)}, either kind)")
    twin = Path(fmu_dir) / setup.paths[ctrl].name  # a native controller's Python twin (its interface)
    if (settings.replan_payload_mass is not None or settings.identify_payload) and setup.kind == "native" and (
            setup.paths[ctrl].stem not in PAYLOAD_DATA_VARIANTS or not twin.is_file()):
        raise ScenarioError(f"fmus.{ctrl}: a re-planned slew is built into the native "
                            f"{' or '.join(PAYLOAD_DATA_VARIANTS)} (from their Python twin in {fmu_dir}), not "
                            f"{setup.paths[ctrl].name}")
    return sensors[0], ctrl, twin


def _open_journal(folder: Path, config: dict, settings) -> tuple[Journal, list[dict]]:
    """The run's journal and the trials it holds; ScenarioError for an edited, gapped or foreign journal."""
    journal = Journal(folder / "journal.jsonl")
    records = journal.read()
    trial_keys = sorted(k for k in records if k.startswith("trial-"))
    if journal.tampered or trial_keys != [f"trial-{j:03d}" for j in range(len(trial_keys))]:
        # each trial learns from the one before: an edited or missing line cannot be run again alone
        raise ScenarioError(f"{journal.problems() or folder / 'journal.jsonl'}"
                            f"{'' if journal.tampered else ': its trials are not consecutive'}; "
                            "remove that folder or choose another --out")
    if records:
        old = records.get("config", {})
        same = {k: old.get(k) for k in config if k != "settings"} == {k: v for k, v in config.items()
                                                                      if k != "settings"}
        old_settings = dict(old.get("settings", {}), trials=settings.trials)
        if not same or old_settings != settings.as_dict():
            raise ScenarioError(f"{folder / 'journal.jsonl'}: written by another configuration (scenario "
                                "file, ILC settings, FMUs or data differ); remove that folder or choose "
                                "another --out")
    else:
        journal.append(config)
    return journal, [records[k] for k in trial_keys]


class _Learning:
    """One ILC run's trials and evaluation: the slew in force (:attr:`stage`, switched once when the payload is
    identified), the controller copies each trial runs with, the corrections and the safeguard."""

    def __init__(self, scenario, settings, setup, sensor: str, ctrl: str, twin: Path, folder: Path, chain: dict,
                 first: int, progress):
        self.scenario, self.settings, self.setup, self.sensor, self.ctrl, self.twin = (scenario, settings, setup,
                                                                                       sensor, ctrl, twin)
        self.folder, self.chain, self.first, self.progress = folder, chain, first, progress
        self.cases = {c.key: c for c in scenario.cases}
        self.record = setup.record + [(sensor, m) for m in MEASURED if (sensor, m) not in setup.record]
        self.corrections = folder / "corrections"
        self.corrections.mkdir(exist_ok=True)
        self.trial_fmus = folder / ".trial_fmus"  # the controller with each trial's correction (removed at the end)
        self.trial_fmus.mkdir(exist_ok=True)
        self.commit = git_commit()
        self.stage = None
        self.guard = None
        self._master = None

    def close(self) -> None:
        if self._master is not None:
            self._master.close()
            self._master = None
        shutil.rmtree(self.trial_fmus, ignore_errors=True)

    def _run(self, correction: str, parameters: dict, n: int) -> dict:
        """One run of the FMUs, the controller carrying `correction` ("": none; a copy even then, so that a
        controller FMU that already carried one runs without it)."""
        from fmu_build.learned import with_learned_feedforward

        fmu = with_learned_feedforward(self.stage.base, Path(correction) if correction else None,
                                       self.trial_fmus / self.setup.paths[self.ctrl].name, self.stage.data_dir)
        self._master = dataclasses.replace(self.stage.setup, paths={**self.setup.paths, self.ctrl: fmu}).open_master(
            self.scenario.algorithm)  # opening checks the correction it runs with
        t0 = time.perf_counter()
        res = self._master.run(self.stage.setup.case_parameters(parameters), self.record, n, self.scenario.step_size)
        res["wall_time_s"] = time.perf_counter() - t0  # the run alone, as a trial's line reports it
        self._master.close()
        self._master = None
        return res

    def correction_of(self, trial: int, file: str) -> np.ndarray:
        """The correction trial `trial` ran with (none before the learning's first trial)."""
        from flexarm import ilc

        return (np.zeros((self.setup.n_steps, 2)) if trial <= self.first
                else ilc.read_learned_feedforward(file, self.stage.data_dir).correction)

    def trials(self, rows: list[dict], journal: Journal) -> str | None:
        """Run the trials after those in `rows` (appended to it and to the journal); what stopped them, or None."""
        settings, progress = self.settings, self.progress
        done = len(rows)
        stopped = (f"trial {done - 1}: {rows[-1]['status']} ({rows[-1].get('message', '')})"
                   if done and rows[-1]["status"] != "ok" else None)
        guarded = [r["safeguard"] for r in rows if r.get("safeguard")]
        if guarded:
            from flexarm.ilc_trial import Safeguard

            self.guard = Safeguard(guarded[-1]["base_trial"], guarded[-1]["lowest_norm_rad"], guarded[-1]["step"])
        learn = self.cases[settings.learn_case]
        if done:
            progress(f"resuming {self.scenario.name} after trial {done - 1} ({self.folder / 'journal.jsonl'})")
        progress(trial_header())
        for row in rows:
            progress(trial_line(row))
        for j in range(done, settings.trials if stopped is None else done):
            file = f"{self.corrections / f'trial_{j:03d}'}.npz" if j > self.first else ""
            params = _with(learn.parameters, self.sensor, {"noise_seed": settings.seed_base + j, "noise_enabled":
                                                           learn.parameters.get(self.sensor, {}).get("noise_enabled",
                                                                                                     True)})
            res = self._run(file, params, self.setup.n_steps)
            row = {"key": f"trial-{j:03d}", "trial": j, "seed": settings.seed_base + j, "status": res["status"],
                   "message": res["message"], "wall_time_s": res["wall_time_s"],
                   "correction_file": checkout_relative(Path(file)) if file else "", "commit": self.commit,
                   "reference": self.stage.reference()}
            if res["status"] == "ok":
                self._learn(j, file, res, row)
            else:
                stopped = f"trial {j}: {res['status']} ({res['message']})"
            journal.append(row)
            rows.append(row)
            progress(trial_line(row))
            if stopped:
                break
        return stopped

    def _learn(self, j: int, file: str, res: dict, row: dict) -> None:
        """Score trial `j` into `row`, then identify and re-plan (before the learning's first trial) or write the
        next trial's correction."""
        from flexarm import ilc
        from flexarm.control import PEAK_TORQUE

        stage, corrections = self.stage, self.corrections
        sig = res["signals"]
        meas = np.column_stack([sig[f"{self.sensor}.{v}"] for v in MEASURED])
        err = ilc.measured_errors(meas[:, :2], meas[:, 2:], stage.traj)
        row["metrics"] = trial_metrics(res, stage.setup, stage.traj, stage.n_slew, float(np.linalg.norm(err)))
        if j < self.first:  # identify the payload from this trial, re-plan, and learn on that slew from now on
            from flexarm.payload_data import write_payload_data

            row["identified"] = identified = identified_payload(res, stage, self.sensor)
            self.progress(f"identified payload {identified['payload_mass_kg']:.4f} kg (rms residual "
                          f"{identified['rms_residual_deg']:.4f}°); re-planning the slew for "
                          f"{identified['planned_for_kg']:g} kg")
            data = write_payload_data(identified["planned_for_kg"], self.folder / "payload_data", self.progress)
            self.stage = make_stage(self.settings, self.setup, data.trajectory(), data, self.setup.paths[self.ctrl],
                                    self.trial_fmus, self.twin)
            return
        u = self.correction_of(j, file)
        if not self.settings.safeguard:
            nxt = stage.law.update(u, err, stage.feedforward, PEAK_TORQUE)
        else:  # flexarm.ilc_trial.Safeguard: no update kept that makes the measured error worse
            from flexarm.ilc_trial import Safeguard

            np.save(corrections / f"errors_{j:03d}.npy", err)  # an update may start here again
            norm = row["metrics"]["measured_error_2norm_rad"]
            self.guard, lowest = (Safeguard(j, norm), True) if self.guard is None else self.guard.after(j, norm)
            row["safeguard"] = {"new_lowest": lowest, **self.guard.as_dict()}
            b = self.guard.base_trial
            u_b = u if b == j else self.correction_of(b, f"{corrections / f'trial_{b:03d}'}.npz")
            e_b = err if b == j else np.load(corrections / f"errors_{b:03d}.npy")
            nxt = self.guard.next_correction(u_b, stage.law.update(u_b, e_b, stage.feedforward, PEAK_TORQUE))
        meta = dict(_learned_metadata(self.scenario, self.settings, self.chain, self.commit, stage.data),
                    trials_learned_from=j + 1 - self.first,
                    last_trial={"trial": j, "seed": self.settings.seed_base + j, **row["metrics"]})
        ilc.write_learned_feedforward(corrections / f"trial_{j + 1:03d}", nxt, stage.model.dt, meta)

    def evaluate(self, n_trials: int) -> dict:
        """The final correction written out and packed into ``learned_controller.fmu``, and each evaluation case run
        without and with it ({} when no trial wrote one)."""
        from fmu_build.learned import with_learned_feedforward

        folder, stage, settings = self.folder, self.stage, self.settings
        final = self.corrections / f"trial_{n_trials:03d}.npz"
        if not final.is_file():
            return {}
        write_atomic(folder / "learned_feedforward.npz", final.read_bytes())
        write_atomic(folder / "learned_feedforward.json", final.with_suffix(".json").read_bytes())
        with_learned_feedforward(stage.base, folder / "learned_feedforward.npz", folder / LEARNED_CONTROLLER,
                                 stage.data_dir)
        n_eval = settings.evaluate_samples
        des_eval = desired_states(stage.traj, np.arange(n_eval + 1) * self.scenario.step_size)
        evaluation = {}
        for key in settings.evaluate_cases:
            params = _with(self.cases[key].parameters, self.sensor, {"noise_seed": settings.seed_base + n_trials})
            evaluation[key] = {"parameters": params}  # as run: scenarios.ilc.masters runs them again
            for label, file in (("unlearned", ""), ("learned", str(final))):
                res = self._run(file, params, n_eval)
                evaluation[key][label] = {"status": res["status"], "message": res["message"]}
                if res["status"] == "ok":
                    evaluation[key][label]["metrics"] = trial_metrics(res, stage.setup, stage.traj, stage.n_slew,
                                                                      float("nan"), des_eval)
        return evaluation


def _with(parameters: dict, inst: str, values: dict) -> dict:
    out = {k: dict(v) for k, v in parameters.items()}
    out.setdefault(inst, {}).update(values)
    return out


def _learned_metadata(scenario, settings, chain, commit, data=None) -> dict:
    from flexarm.gain_schedule import relative_path
    from flexarm.parameters import DEFAULT_PARAMETER_FILE
    from flexarm.trajectory import DEFAULT_TRAJECTORY_FILE

    ctrl = scenario.parameters.get("controller", {})
    # relative to the checkout (flexarm/data/...: resolved against the package when read, or against the payload
    # data folder it was learnt on, which is the FMU's own data folder once packed), no absolute path
    trajectory = DEFAULT_TRAJECTORY_FILE if data is None else data.trajectory_file
    return {"trajectory_file": relative_path(DEFAULT_TRAJECTORY_FILE),
            "trajectory_sha256": sha256_file(trajectory),
            "reference": "committed" if data is None else f"re-planned for {data.payload_mass:g} kg",
            "parameter_file": relative_path(DEFAULT_PARAMETER_FILE),
            "parameter_sha256": sha256_file(DEFAULT_PARAMETER_FILE),
            "gain_set": ctrl.get("gain_set", "gamma0.1"), "schedule_period_s": ctrl.get("schedule_period", 0.2),
            "ilc": settings.as_dict(), "ilc_method": "norm-optimal (Amann, Owens, Rogers), Riccati/adjoint sweep, "
            "zero-phase Butterworth Q-filter, clipped to the motors' peak torques (flexarm.ilc)",
            "scenario": scenario.name, "scenario_sha256": sha256_file(scenario.path),
            "learn_case_parameters": {c.key: c.parameters for c in scenario.cases}.get(settings.learn_case),
            "data_sha256": chain, "commit": commit}


def refuse_run_options(args) -> None:
    """ScenarioError (exit 2) for a ``run`` option an ILC scenario does not honour, naming it and why.

    An ILC run learns the feedforward of its own controller FMU on its own cases and parameters, and writes what
    it learnt under the scenario's name: running it with a user's controller, another case or a changed parameter
    while reporting the scenario's figures would present our controller's numbers as the user's. Refused, never
    ignored.
    """
    given = [(flag, value) for flag, value in (("--controller", getattr(args, "controller", None)),
                                               ("--set", getattr(args, "sets", None)),
                                               ("--case", getattr(args, "cases", None))) if value]
    if given:
        flags = ", ".join(f"{flag} {' '.join(map(str, v)) if isinstance(v, list) else v}" for flag, v in given)
        raise ScenarioError(
            f"run {args.scenario_name}: {flags}: an ILC scenario learns the feedforward of its own controller on "
            "the cases and parameters of its file, so these options would not apply to what it runs and reports; "
            "copy the scenario file, edit its [fmus], [parameters] or [ilc] learn_case / evaluate_cases, and run "
            "that file instead")


def cli(args) -> int:
    """``python -m scenarios run`` for an ILC scenario (called by :mod:`scenarios.__main__`)."""
    refuse_run_options(args)
    summary = run_ilc(args.scenario_name, args.out, args.fmu_dir, args.kind, args.native_fmu_dir,
                      plots=not args.no_plots, progress=lambda s: print(s, flush=True))
    for key, ev in summary["evaluation"].items():
        parts = []
        for label in ("unlearned", "learned"):
            r = ev[label]
            parts.append(f"{label} " + (f"rms {r['metrics']['slew_rms_position_error']:.4f}° peak τ "
                                        f"{r['metrics']['slew_peak_tau1']:.3f}/{r['metrics']['slew_peak_tau2']:.3f} N·m"
                                        if r.get("metrics") else r["status"]))
        print(f"   {key}: " + "; ".join(parts))
    print(f"   results: {Path(args.out) / summary['scenario']}")
    if summary["stopped"]:
        print(f"   stopped: {summary['stopped']}", file=sys.stderr)
        return 1
    return 0
