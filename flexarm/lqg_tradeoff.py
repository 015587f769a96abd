"""What the Kalman filter's process noise trades: rejecting sensor noise against absorbing the payload.

Issue 14 asks two things of one LQG design: that sensor noise raise its rms position error by at most
2× (Table 1's weights, γ = 1) and that it at least halve the LQR's error with the 0.275 kg payload. The
process noise W of the filter decides both. A large tip force in W (the payload the filter must absorb)
makes the filter fast: it follows the payload's force, and passes the encoders' noise on. A small W makes
it trust the model: the noise stays out, and so does the payload. This module designs the LQG for a few
process-noise models and runs the library loop (delay 2, as under a Jacobi master) to show where each
lands; ``python -m scenarios results-page`` prints the table on the results page, and
``python -m flexarm.lqg_tradeoff`` prints it alone. The last row is the multiple-model bank of
:mod:`flexarm.lqg_bank`, which does not trade: it knows the payload as a family of models.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .gain_schedule import default_trajectory_path
from .lqg import LqgController, simulate_lqg
from .lqg_bank import DEFAULT_MASSES, BankController, design_bank, load_bank
from .lqg_design import ELEMENT_FORCE_SIGMA, MOTOR_TORQUE_SIGMA, PAYLOAD_MASS_KG, design_lqg
from .model import ArmModel, N
from .parameters import load_parameters
from .sensors import SensorBank, SensorSettings

#: Process-noise models compared: (label, payload mass in W, kg; scale of the motor and model-error terms).
FILTERS = (
    ("committed", PAYLOAD_MASS_KG, 1.0),
    ("payload ÷10", 0.1 * PAYLOAD_MASS_KG, 1.0),
    ("payload ÷100, model ÷100", 0.01 * PAYLOAD_MASS_KG, 0.01),
    ("no payload, model ÷100", 0.0, 0.01),
)
#: The loop delay the comparison runs at (a Jacobi master with separate sensors and controller FMUs).
LOOP_DELAY = 2
NOISE_SEED = 1
#: Label of the multiple-model bank's row.
BANK_LABEL = f"bank of {len(DEFAULT_MASSES)} payload models ({DEFAULT_MASSES[0]:g}-{DEFAULT_MASSES[-1]:g} kg)"


@dataclass(frozen=True)
class TradeoffRow:
    """One process-noise model and what it gives (rms position errors over all 11 elements, degrees).

    Attributes
    ----------
    label : str
    payload_mass : float
        Payload the filter's W absorbs, kg.
    model_scale : float
        Scale of the motor-torque and model-error terms of W (1 = the committed design).
    quiet, noisy : float
        γ = 1 (Table 1's weights), no payload, without and with sensor noise.
    quiet_integral, noisy_integral : float
        The same with integral action.
    payload : float
        0.275 kg payload, noise, γ = 0.1, integral action.
    payload_peak_tau : tuple of float
        Its peak torques, N·m.
    """

    label: str
    payload_mass: float
    model_scale: float
    quiet: float
    noisy: float
    quiet_integral: float
    noisy_integral: float
    payload: float
    payload_peak_tau: tuple[float, float]


def _rms_position_deg(states, controller: LqgController) -> float:
    n = len(states) - 1
    err = states[:n, :N] - controller.z[:n, :N]
    return float(np.degrees(np.sqrt(np.mean(err**2))))


def tradeoff_row(label: str, payload_mass: float, model_scale: float) -> TradeoffRow:
    """Design the LQG with this process noise (200 ms schedule) and run the five library loops."""
    params = load_parameters()
    traj = default_trajectory_path()
    design = design_lqg(ArmModel(params), traj, "200ms", payload_mass=payload_mass,
                        motor_torque_sigma=model_scale * MOTOR_TORQUE_SIGMA,
                        element_force_sigma=model_scale * ELEMENT_FORCE_SIGMA)
    return _measured_row(label, payload_mass, model_scale, lambda gain_set, integral: LqgController(
        traj, design, gain_set, LOOP_DELAY, integral, params.peak_torque))


def bank_tradeoff_row(masses=DEFAULT_MASSES) -> TradeoffRow:
    """The same five loops with the multiple-model bank (:mod:`flexarm.lqg_bank`; no payload in any W):
    the committed bank (what ``controller_lqg``'s ``estimator = payload_bank`` runs) for the default masses."""
    params = load_parameters()
    traj = default_trajectory_path()
    bank = load_bank() if tuple(masses) == DEFAULT_MASSES else design_bank(params, masses, traj)
    label = BANK_LABEL if tuple(masses) == DEFAULT_MASSES else f"bank of payload models {tuple(masses)} kg"
    return _measured_row(label, 0.0, 1.0, lambda gain_set, integral: BankController(
        traj, bank, gain_set, LOOP_DELAY, integral, params.peak_torque))


def _measured_row(label: str, payload_mass: float, model_scale: float, make_controller) -> TradeoffRow:
    """Run the five loops with controllers from ``make_controller(gain_set, integral_action)``."""
    params = load_parameters()
    model, loaded = ArmModel(params), ArmModel(params.with_payload(PAYLOAD_MASS_KG))

    def run(plant, gain_set, integral, noise):
        c = make_controller(gain_set, integral)
        sensors = SensorBank(SensorSettings(noise_enabled=True, noise_seed=NOISE_SEED)) if noise else None
        states, torques = simulate_lqg(plant, c, sensors=sensors)
        return _rms_position_deg(states, c), tuple(float(v) for v in np.max(np.abs(torques), axis=0))

    quiet, noisy = run(model, "gamma1", False, False)[0], run(model, "gamma1", False, True)[0]
    quiet_i, noisy_i = run(model, "gamma1", True, False)[0], run(model, "gamma1", True, True)[0]
    payload, peak = run(loaded, "gamma0.1", True, True)
    return TradeoffRow(label, payload_mass, model_scale, quiet, noisy, quiet_i, noisy_i, payload, peak)


def tradeoff_rows(filters=FILTERS, progress=None, bank: bool = True) -> list[TradeoffRow]:
    """:func:`tradeoff_row` for each ``(label, payload_mass, model_scale)``, then (``bank``)
    :func:`bank_tradeoff_row`; ``progress(label)`` before each."""
    rows = []
    for label, mass, scale in filters:
        if progress is not None:
            progress(label)
        rows.append(tradeoff_row(label, mass, scale))
    if bank:
        if progress is not None:
            progress(BANK_LABEL)
        rows.append(bank_tradeoff_row())
    return rows


def tradeoff_markdown(rows: list[TradeoffRow]) -> str:
    """The rows as a Markdown table (rms position errors in degrees, ratios noisy ÷ quiet)."""
    lines = ["| filter's process noise | payload in W, kg | γ = 1: quiet → noisy | with integral action | "
             "payload + noise, γ = 0.1 + I | its peak torques, N·m |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        ratio, ratio_i = r.noisy / r.quiet, r.noisy_integral / r.quiet_integral
        lines.append(f"| {r.label} | {r.payload_mass:.4g} | {r.quiet:.4f}° → {r.noisy:.4f}° (×{ratio:.1f}) | "
                     f"{r.quiet_integral:.4f}° → {r.noisy_integral:.4f}° (×{ratio_i:.1f}) | "
                     f"{r.payload:.2f}° | {r.payload_peak_tau[0]:.2f} / {r.payload_peak_tau[1]:.2f} |")
    return "\n".join(lines)


def main() -> int:
    import sys

    rows = tradeoff_rows(progress=lambda label: print(f"designing and running: {label}", file=sys.stderr,
                                                      flush=True))
    print(tradeoff_markdown(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
