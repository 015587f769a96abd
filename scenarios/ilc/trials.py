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
import math
import shutil
import sys
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from flexarm.provenance import git_commit, sha256_file, write_atomic, write_json
from scenarios.config import SCENARIO_DIR, Scenario, ScenarioError, load_scenario
from scenarios.metrics import table_metrics
from scenarios.results import portable
from scenarios.run.fmus import DEFAULT_FMU_DIR, DEFAULT_NATIVE_FMU_DIR, fmu_kind
from scenarios.run.outdir import check_writable, folder_lock, remove_stale
from scenarios.run.runner import N_EL
from scenarios.run.setup import _relative, desired_states, desired_trajectory, prepare, verify_data_chain
from scenarios.sweep.journal import Journal

#: The measurements the learning reads (sensors FMU outputs): encoders, then strain gauges.
MEASURED = ("q1_m", "q2_m", "eps1_m", "eps2_m", "eps3_m", "eps4_m", "eps5_m", "eps6_m")
#: Keys of the [ilc] table and what each allows.
ILC_KEYS = {
    "trials": "an integer in [1, 1000]",
    "learn_case": "the key of a case in [[cases]]",
    "seed_base": "an integer >= 0 (trial j uses noise seed seed_base + j)",
    "model_payload_mass": "a payload in [0, 10] kg for the learning's model",
    "settling_model_payload_mass": "a payload in [0, 10] kg for the learning's model at and after t_f "
                                   "(default: model_payload_mass)",
    "error_weight": "a weight > 0, rad^-2",
    "input_weight": "a weight > 0, (N m)^-2",
    "leak_weight": "a weight >= 0, (N m)^-2",
    "learning_gain": "a step factor in (0, 2)",
    "settling_weight": "a factor in [0, 1e6] on error_weight for the samples at and after t_f (1: none)",
    "settling_tip_weight": "a weight in [0, 1e12] m^-2 on the tip deviation the measured angles imply, at and "
                           "after t_f (0: none)",
    "q_filter_cutoff_hz": "a cut-off in [0, 500) Hz (0: no Q-filter)",
    "q_filter_order": "an integer in [1, 8]",
    "settling_q_filter_cutoff_hz": "a cut-off in [0, 500) Hz for the Q-filter at and after t_f (0: none; default "
                                   "q_filter_cutoff_hz)",
    "evaluate_cases": "a list of case keys",
    "evaluate_samples": "an integer in [scenario.samples, 100000]: the length of the evaluate_cases runs, 1 ms "
                        "samples (the correction is zero past its own samples; default scenario.samples)",
}
#: Tip distance to the end point that counts as arrived, m.
TIP_TOLERANCE_M = 1e-3
#: In an ILC result folder: the controller FMU with the final correction inside it.
LEARNED_CONTROLLER = "learned_controller.fmu"


@dataclass
class IlcSettings:
    trials: int
    learn_case: str
    seed_base: int
    model_payload_mass: float
    settling_model_payload_mass: float
    error_weight: float
    input_weight: float
    leak_weight: float
    learning_gain: float
    settling_weight: float
    settling_tip_weight: float
    q_filter_cutoff_hz: float
    q_filter_order: int
    settling_q_filter_cutoff_hz: float
    evaluate_cases: list[str]
    evaluate_samples: int

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def _ilc_table(path: Path) -> dict | None:
    try:
        doc = tomllib.loads(path.read_bytes().decode("utf-8"))
    except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError, RecursionError):
        return None  # not an ILC scenario; load_scenario then refuses the file naming what is wrong
    return doc.get("ilc")


def _path(name) -> Path:
    p = Path(name)
    return SCENARIO_DIR / f"{p.name}.toml" if not p.suffix else p


def is_ilc_scenario(name) -> bool:
    """Whether the scenario name or file has an ``[ilc]`` table (run by :func:`run_ilc`)."""
    p = _path(name)
    return p.is_file() and _ilc_table(p) is not None


def load_ilc(name) -> tuple[Scenario, IlcSettings]:
    """The scenario (validated by :func:`scenarios.config.load_scenario`) and its ``[ilc]`` settings, each
    refused naming the field and what it allows."""
    scenario = load_scenario(name)
    raw = _ilc_table(scenario.path) or {}
    where = f"{scenario.path.name}: ilc"
    unknown = set(raw) - set(ILC_KEYS)
    if unknown:
        raise ScenarioError(f"{where}: keys allowed: {sorted(ILC_KEYS)}, got {sorted(unknown)}")
    keys = [c.key for c in scenario.cases]

    def get(key, default, ok):
        v = raw.get(key, default)
        if not ok(v):
            raise ScenarioError(f"{where}.{key}: {ILC_KEYS[key]}, got {v!r}")
        return v

    def integer(lo, hi):
        return lambda v: isinstance(v, int) and not isinstance(v, bool) and lo <= v <= hi

    def number(lo, hi, lo_open=False):
        return lambda v: (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                          and (v > lo if lo_open else v >= lo) and v <= hi)

    s = IlcSettings(
        trials=get("trials", 10, integer(1, 1000)),
        learn_case=get("learn_case", keys[0], lambda v: v in keys),
        seed_base=get("seed_base", 1, integer(0, 2**62)),
        model_payload_mass=float(get("model_payload_mass", 0.0, number(0.0, 10.0))),
        settling_model_payload_mass=float(get("settling_model_payload_mass", raw.get("model_payload_mass", 0.0),
                                              number(0.0, 10.0))),
        error_weight=float(get("error_weight", 1.0, number(0.0, 1e12, True))),
        input_weight=float(get("input_weight", 1e-4, number(0.0, 1e12, True))),
        leak_weight=float(get("leak_weight", 0.0, number(0.0, 1e12))),
        learning_gain=float(get("learning_gain", 1.0, lambda v: number(0.0, 1.999999, True)(v))),
        settling_weight=float(get("settling_weight", 1.0, number(0.0, 1e6))),
        settling_tip_weight=float(get("settling_tip_weight", 0.0, number(0.0, 1e12))),
        q_filter_cutoff_hz=float(get("q_filter_cutoff_hz", 10.0, lambda v: number(0.0, 499.999)(v))),
        q_filter_order=get("q_filter_order", 2, integer(1, 8)),
        settling_q_filter_cutoff_hz=float(get("settling_q_filter_cutoff_hz", raw.get("q_filter_cutoff_hz", 10.0),
                                              lambda v: number(0.0, 499.999)(v))),
        evaluate_cases=list(get("evaluate_cases", [], lambda v: isinstance(v, list) and all(x in keys for x in v))),
        evaluate_samples=0,
    )
    if scenario.samples == "trajectory":
        raise ScenarioError(f"{scenario.path.name}: scenario.samples: an integer number of samples for an ILC "
                            "scenario (the slew and the settling after it), got \"trajectory\"")
    s.evaluate_samples = get("evaluate_samples", scenario.samples, integer(scenario.samples, 100_000))
    if abs(scenario.step_size - 1e-3) > 1e-12:
        raise ScenarioError(f"{scenario.path.name}: scenario.step_size_s: 0.001 for an ILC scenario (the learning "
                            f"works on the 1 ms samples), got {scenario.step_size!r}")
    return scenario, s


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
    limits = np.array([7.0, 2.25])
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
def _config_record(scenario, settings, setup, chain) -> dict:
    return {"key": "config", "scenario_sha256": sha256_file(scenario.path), "settings": settings.as_dict(),
            "fmu_sha256": {i: sha256_file(p) for i, p in setup.paths.items()}, "data_sha256": chain,
            "samples": setup.n_steps, "fmu_kind": setup.kind}


def run_ilc(name, out_dir: Path, fmu_dir: Path = DEFAULT_FMU_DIR, kind: str | None = None,
            native_fmu_dir: Path = DEFAULT_NATIVE_FMU_DIR, plots: bool = True, progress=print,
            trials: int | None = None) -> dict:
    """Run (or resume) an ILC scenario; returns the summary written to ``evaluation.json``.

    `trials` overrides the file's number of trials (e.g. a short check). Raises :class:`ScenarioError` for
    refused input, :class:`scenarios.run.outdir.OutputError` for an unusable folder; a trial that ends unbounded
    or with an FMU error stops the learning (the journal keeps it) and is reported in the summary's ``stopped``.
    """
    from flexarm import ilc
    from flexarm.control import PEAK_TORQUE
    from fmu_build.learned import LEARNING_CONTROLLERS, with_learned_feedforward

    scenario, settings = load_ilc(name)
    if trials is not None:
        settings.trials = int(trials)
    chain = verify_data_chain()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    folder = out / scenario.name
    with folder_lock(out, scenario.name):
        remove_stale(out, scenario.name, folder)
        check_writable(folder, 2_000_000 * (settings.trials + 2))
        cases = {c.key: c for c in scenario.cases}
        setup = prepare(scenario, fmu_dir, kind=kind, native_fmu_dir=native_fmu_dir)
        sensors = [inst for inst, md in setup.descriptions.items()
                   if all(any(v.name == m for v in md.modelVariables) for m in MEASURED)]
        ctrl = setup.driver
        if not sensors:
            raise ScenarioError(f"{scenario.path.name}: no FMU outputs the measurements {list(MEASURED)}")
        md = setup.descriptions[ctrl]
        if fmu_kind(md) == "other" or md.coSimulation.modelIdentifier not in LEARNING_CONTROLLERS:
            raise ScenarioError(f"fmus.{ctrl}: {setup.paths[ctrl].name} does not read a learned feedforward; ILC "
                                f"runs need one of our controllers that does ({', '.join(LEARNING_CONTROLLERS)})")
        record = setup.record + [(sensors[0], m) for m in MEASURED if (sensors[0], m) not in setup.record]
        traj = desired_trajectory()
        n = setup.n_steps
        n_slew = min(traj.n_samples, n)
        model = ilc.closed_loop_model(n, payload_mass=settings.model_payload_mass)
        if settings.settling_model_payload_mass != settings.model_payload_mass:
            # the samples at and after t_f (state x_k, k >= n_slew) move by the arm with the other payload
            after = ilc.closed_loop_model(n, payload_mass=settings.settling_model_payload_mass)
            model = ilc.spliced_model(model, after, n_slew)
        time_weight, output_weight = ilc.settling_weights(traj, n, settings.settling_weight,
                                                          settings.settling_tip_weight)
        law = _law(settings, model, n_slew, time_weight, output_weight)
        feedforward = ilc.feedforward_over(traj, n)
        journal = Journal(folder / "journal.jsonl")
        records = journal.read()
        trial_keys = sorted(k for k in records if k.startswith("trial-"))
        if journal.tampered or trial_keys != [f"trial-{j:03d}" for j in range(len(trial_keys))]:
            # each trial learns from the one before: an edited or missing line cannot be run again alone
            raise ScenarioError(f"{journal.problems() or folder / 'journal.jsonl'}"
                                f"{'' if journal.tampered else ': its trials are not consecutive'}; "
                                "remove that folder or choose another --out")
        config = _config_record(scenario, settings, setup, chain)
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
        corrections = folder / "corrections"
        corrections.mkdir(exist_ok=True)
        commit = git_commit()
        base_meta = _learned_metadata(scenario, settings, chain, commit)
        stopped = None
        rows = [records[k] for k in sorted(k for k in records if k.startswith("trial-"))]
        done = len(rows)
        if done and rows[-1]["status"] != "ok":
            stopped = f"trial {done - 1}: {rows[-1]['status']} ({rows[-1].get('message', '')})"
        trial_fmus = folder / ".trial_fmus"  # the controller with each trial's correction (removed at the end)
        trial_fmus.mkdir(exist_ok=True)

        def open_master(correction: str):
            """A master whose controller carries `correction` ("" : none; a copy even then, so that a
            controller FMU that already carried one runs without it)."""
            fmu = with_learned_feedforward(setup.paths[ctrl], Path(correction) if correction else None,
                                           trial_fmus / setup.paths[ctrl].name)
            return dataclasses.replace(setup, paths={**setup.paths, ctrl: fmu}).open_master(scenario.algorithm)

        m = None
        try:
            learn = cases[settings.learn_case]
            if done:
                progress(f"resuming {scenario.name} after trial {done - 1} ({folder / 'journal.jsonl'})")
            progress(_header())
            for row in rows:
                progress(_line(row))
            for j in range(done, settings.trials if stopped is None else done):
                stem = corrections / f"trial_{j:03d}"
                file = f"{stem}.npz" if j else ""
                m = open_master(file)  # checks the correction this trial runs with
                params = _with(learn.parameters, sensors[0], {"noise_seed": settings.seed_base + j, "noise_enabled":
                                                    learn.parameters.get(sensors[0], {}).get("noise_enabled", True)})
                t0 = time.perf_counter()
                res = m.run(setup.case_parameters(params), record, n, scenario.step_size)
                wall = time.perf_counter() - t0
                m.close()
                m = None
                row = {"key": f"trial-{j:03d}", "trial": j, "seed": settings.seed_base + j, "status": res["status"],
                       "message": res["message"], "wall_time_s": wall, "correction_file": _relative(Path(file))
                       if file else "", "commit": commit}
                if res["status"] == "ok":
                    sig = res["signals"]
                    meas = np.column_stack([sig[f"{sensors[0]}.{v}"] for v in MEASURED])
                    err = ilc.measured_errors(meas[:, :2], meas[:, 2:], traj)
                    row["metrics"] = trial_metrics(res, setup, traj, n_slew, float(np.linalg.norm(err)))
                    u = np.zeros((n, 2)) if not j else ilc.read_learned_feedforward(file).correction
                    nxt = law.update(u, err, feedforward, PEAK_TORQUE)
                    meta = dict(base_meta, trials_learned_from=j + 1,
                                last_trial={"trial": j, "seed": settings.seed_base + j, **row["metrics"]})
                    ilc.write_learned_feedforward(corrections / f"trial_{j + 1:03d}", nxt, model.dt, meta)
                else:
                    stopped = f"trial {j}: {res['status']} ({res['message']})"
                journal.append(row)
                rows.append(row)
                progress(_line(row))
                if stopped:
                    break
            evaluation = {}
            final = corrections / f"trial_{len(rows):03d}.npz"
            if stopped is None and final.is_file():
                write_atomic(folder / "learned_feedforward.npz", final.read_bytes())
                write_atomic(folder / "learned_feedforward.json", (corrections / f"trial_{len(rows):03d}.json")
                             .read_bytes())
                with_learned_feedforward(setup.paths[ctrl], folder / "learned_feedforward.npz",
                                         folder / LEARNED_CONTROLLER)
                n_eval = settings.evaluate_samples
                des_eval = desired_states(traj, np.arange(n_eval + 1) * scenario.step_size)
                for key in settings.evaluate_cases:
                    case = cases[key]
                    evaluation[key] = {}
                    for label, file in (("unlearned", ""), ("learned", str(final))):
                        params = _with(case.parameters, sensors[0], {"noise_seed": settings.seed_base + len(rows)})
                        m = open_master(file)
                        res = m.run(setup.case_parameters(params), record, n_eval, scenario.step_size)
                        m.close()
                        m = None
                        evaluation[key][label] = {"status": res["status"], "message": res["message"]}
                        if res["status"] == "ok":
                            evaluation[key][label]["metrics"] = trial_metrics(res, setup, traj, n_slew, float("nan"),
                                                                              des_eval)
        finally:
            journal.close()
            if m is not None:
                m.close()
            shutil.rmtree(trial_fmus, ignore_errors=True)
        summary = {"scenario": scenario.name, "scenario_sha256": sha256_file(scenario.path), "commit": commit,
                   "settings": settings.as_dict(), "fmu_kind": setup.kind,
                   "fmu_sha256": {i: sha256_file(p) for i, p in setup.paths.items()}, "data_sha256": chain,
                   "samples": n, "slew_samples": n_slew, "trials": rows, "stopped": stopped,
                   "evaluation": evaluation}
        if evaluation:
            summary["learned_controller"] = {"file": LEARNED_CONTROLLER,
                                             "sha256": sha256_file(folder / LEARNED_CONTROLLER)}
        write_json(folder / "evaluation.json", portable(summary, folder))
        _write_csv(folder / "trials.csv", rows)
        if plots and rows:
            plot_convergence(rows, folder / "convergence.png", scenario.name)
    return summary


def _law(settings: IlcSettings, model, n_slew: int, time_weight, output_weight):
    """The learning law of the settings (:class:`flexarm.ilc.NormOptimalIlc`)."""
    from flexarm import ilc

    q = ({} if settings.settling_q_filter_cutoff_hz == settings.q_filter_cutoff_hz else
         {"settling_q_cutoff_hz": settings.settling_q_filter_cutoff_hz, "settling_start": n_slew})
    return ilc.NormOptimalIlc(model, settings.error_weight, settings.input_weight, settings.q_filter_cutoff_hz,
                              settings.q_filter_order, settings.leak_weight, time_weight=time_weight,
                              learning_gain=settings.learning_gain, output_weight=output_weight, **q)


def _with(parameters: dict, inst: str, values: dict) -> dict:
    out = {k: dict(v) for k, v in parameters.items()}
    out.setdefault(inst, {}).update(values)
    return out


def _learned_metadata(scenario, settings, chain, commit) -> dict:
    from flexarm.gain_schedule import relative_path
    from flexarm.parameters import DEFAULT_PARAMETER_FILE
    from flexarm.trajectory import DEFAULT_TRAJECTORY_FILE

    ctrl = scenario.parameters.get("controller", {})
    # relative to the checkout (flexarm/data/...: resolved against the package when read), no absolute path
    return {"trajectory_file": relative_path(DEFAULT_TRAJECTORY_FILE),
            "trajectory_sha256": sha256_file(DEFAULT_TRAJECTORY_FILE),
            "parameter_file": relative_path(DEFAULT_PARAMETER_FILE),
            "parameter_sha256": sha256_file(DEFAULT_PARAMETER_FILE),
            "gain_set": ctrl.get("gain_set", "gamma0.1"), "schedule_period_s": ctrl.get("schedule_period", 0.2),
            "ilc": settings.as_dict(), "ilc_method": "norm-optimal (Amann, Owens, Rogers), Riccati/adjoint sweep, "
            "zero-phase Butterworth Q-filter, clipped to the motors' peak torques (flexarm.ilc)",
            "scenario": scenario.name, "scenario_sha256": sha256_file(scenario.path),
            "learn_case_parameters": {c.key: c.parameters for c in scenario.cases}.get(settings.learn_case),
            "data_sha256": chain, "commit": commit}


COLUMNS = (("trial", "trial", "{:d}"), ("seed", "seed", "{:d}"),
           ("rms pos°", "slew_rms_position_error", "{:.4f}"), ("peak pos°", "slew_peak_position_error", "{:.3f}"),
           ("rms q1°", "rms_q1_error_deg", "{:.4f}"), ("rms q2°", "rms_q2_error_deg", "{:.4f}"),
           ("rms tip mm", "rms_tip_error_mm", "{:.2f}"), ("tip<1mm s", "tip_within_1mm_after_tf_s", "{:.3f}"),
           ("τ1 N·m", "slew_peak_tau1", "{:.3f}"), ("τ2 N·m", "slew_peak_tau2", "{:.3f}"),
           ("sat", "saturated_samples", "{:d}"), ("‖e‖ rad", "measured_error_2norm_rad", "{:.4f}"),
           ("wall s", "wall_time_s", "{:.1f}"))


def _header() -> str:
    return " ".join(f"{h:>10s}" for h, _, _ in COLUMNS)


def _line(row: dict) -> str:
    m = dict(row.get("metrics") or {}, trial=row["trial"], seed=row["seed"], wall_time_s=row["wall_time_s"])
    if row["status"] != "ok":
        return f"{row['trial']:>10d} {row['seed']:>10d} {row['status']}: {row['message']}"
    cells = []
    for _, key, fmt in COLUMNS:
        v = m.get(key)
        cells.append(f"{'---' if v is None else fmt.format(v):>10s}")
    return " ".join(cells)


def _write_csv(path: Path, rows: list[dict]) -> None:
    keys = sorted({k for r in rows for k in (r.get("metrics") or {})})
    lines = [",".join(["trial", "seed", "status", "wall_time_s", *keys])]
    for r in rows:
        m = r.get("metrics") or {}
        lines.append(",".join([str(r["trial"]), str(r["seed"]), r["status"], repr(r["wall_time_s"])]
                              + ["" if m.get(k) is None else repr(m[k]) for k in keys]))
    write_atomic(path, "\n".join(lines) + "\n")


def plot_convergence(rows: list[dict], path: Path, name: str) -> Path:
    """rms / peak position error, tip error and peak torques against the trial number (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import io

    import matplotlib.pyplot as plt

    ok = [r for r in rows if r.get("metrics")]
    j = [r["trial"] for r in ok]
    g = lambda k: [r["metrics"][k] for r in ok]  # noqa: E731
    fig, ax = plt.subplots(3, 1, figsize=(8, 9), sharex=True)
    ax[0].semilogy(j, g("slew_rms_position_error"), "o-", label="rms, all 11 elements")
    ax[0].semilogy(j, g("slew_peak_position_error"), "s-", label="peak, all 11 elements")
    ax[0].semilogy(j, g("rms_q1_error_deg"), "^-", label="rms joint 1")
    ax[0].semilogy(j, g("rms_q2_error_deg"), "v-", label="rms joint 2")
    ax[0].axhline(0.1, color="k", ls=":", lw=1, label="0.1°")
    ax[0].set(ylabel="position error over the slew, °", title=f"{name}: convergence")
    ax[0].legend(fontsize=8)
    ax[1].semilogy(j, g("rms_tip_error_mm"), "o-", label="rms tip error over the slew")
    ax[1].semilogy(j, g("peak_tip_error_mm"), "s-", label="peak tip error over the run")
    ax[1].semilogy(j, [1e3 * v for v in g("measured_error_2norm_rad")], "d-", label="‖measured error‖₂, mrad")
    ax[1].set(ylabel="mm / mrad")
    ax[1].legend(fontsize=8)
    ax[2].plot(j, g("slew_peak_tau1"), "o-", label="peak τ1")
    ax[2].plot(j, g("slew_peak_tau2"), "s-", label="peak τ2")
    ax[2].axhline(7.0, color="C0", ls=":", lw=1)
    ax[2].axhline(2.25, color="C1", ls=":", lw=1)
    ax[2].set(xlabel="trial", ylabel="N·m")
    ax[2].legend(fontsize=8)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    write_atomic(path, buf.getvalue())
    return path


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
