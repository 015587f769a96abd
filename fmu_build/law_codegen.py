"""Generate the native controllers' and sensors' law C from :mod:`flexarm.control_law`, :mod:`flexarm.filter_law`
and :mod:`flexarm.sensor_law` (build time; issue 33 item 4).

As the plant's physics (:mod:`fmu_build.native_codegen`), the laws' arithmetic is not written in C: the functions
the library and the Python FMUs run are evaluated on CasADi SX symbols and code-generated. The C FMUs keep what
is not arithmetic of a law: reading resources, the FMI state, which sample is which, the order of the steps.

Generated into ``<stem>.c``/``.h`` of an FMU's sources as ``generated_*``, called through the ``law_*`` wrappers
of ``<stem>_api.h`` (arguments, then results, as pointers; the work arrays inside). Matrices row-major, as the
resources hold them.

``control_law`` (every controller FMU), from :mod:`flexarm.control_law` and :mod:`flexarm.filter_law`:

* ``law_gain_on_measurements(K[2×22], E[22×10]) -> K E [2×10]`` (:func:`~flexarm.control_law.gain_on_measurements`);
* ``law_gain_offset(K[2×22], E[22×10], m_d[10]) -> K (E m_d) [2]`` as the library forms it
  (:func:`~flexarm.control_law.reconstructed_states`, :func:`~flexarm.control_law.gain_offsets`);
* ``law_tracking_torque(τ_ff[2], K E[2×10], m[10], offset[2], limit[2]) -> τ[2]``
  (:func:`~flexarm.control_law.tracking_torque`);
* ``law_saturate(τ[2], limit[2]) -> τ[2]`` (:func:`~flexarm.control_law.saturate`);
* ``law_has_switched(t_switch, t) -> 1 or 0`` (:func:`~flexarm.control_law.has_switched`, the schedules' rule);
* the LQG's (:mod:`flexarm.filter_law`, products as compensated sums, :func:`~flexarm.law_ops.mat_vec`):
  ``law_time_update_drift(Φ[22×22], Γ[22×2], x[22], Δτ[2], d[22]) -> x⁺``,
  ``law_innovation(x, C[10×22], m, m_d) -> e``, ``law_updated(x, M[22×10], e) -> x_post`` (the two are
  :func:`~flexarm.filter_law.corrected`), ``law_measured(C, x) -> C x``,
  ``law_free_torque(τ_cmd[2], K[2×22], x) -> τ_free`` and ``law_free_torque_integral(.., K_ξ[2×2], ξ[2])``,
  ``law_integrated(ξ, dt, C_q[2×22], x, τ, τ_free) -> ξ'``; the payload bank's per filter
  ``law_log_likelihood_update`` and ``law_feedback`` (``_integral``), and over its filters
  ``law_bank_free_torque(τ_cmd, w[12], u[12×2])`` and ``law_weighted_estimate(w[12], x[12×22])``
  (``LAW_BANK_FILTERS`` = 12, unused filters weighted 0), and its posterior
  ``law_normalised_posterior(log p[12], active[12], log_floor) -> (log p, p)``
  (:func:`~flexarm.filter_law.normalised_posterior`; its exp and log1p are the portable ones), the quiet filter's
  ``law_reseeded(p_0, reseed_below, x_quiet[22], x_unloaded[22]) -> x`` and, at instantiation,
  ``law_state_drift(Ψ[22×11], Δα[11]) -> d`` (:func:`~flexarm.filter_law.state_drift`).

``sensor_law`` (the sensors FMU), one channel per call:

* ``law_filter_section(sos[6], s0, s1, x) -> (y, s0', s1')`` (:func:`~flexarm.sensor_law.filter_section`);
* ``law_primed_state(unit_state[2], x) -> state[2]`` (:func:`~flexarm.sensor_law.primed_state`);
* ``law_with_noise(y, amplitude, uniform) -> y'`` (:func:`~flexarm.sensor_law.with_noise`);
* ``law_quantize(x, lsb, lo_code, hi_code) -> x'`` (:func:`~flexarm.sensor_law.quantize`);
* at initialisation ``law_channel_scales(settings..., κ_FS[2], L[6], ..., 2^bits) -> (amplitude[12], encoder_lsb,
  full_scale[10], adc_lsb[10], lo_code, hi_code)`` (:func:`~flexarm.sensor_law.channel_scales`);
* the Butterworth design at initialisation (:mod:`flexarm.filter_design`): ``law_prewarp_argument(cutoff_hz,
  sample_rate_hz) -> a``, whose tangent the C takes with the portable ``flexarm_tan``, then
  ``law_butterworth_order_<N>(tan a) -> (sos[n×6], unit_state[n×2])`` for N = 1..8, n = (N + 1) / 2 sections.
"""

from __future__ import annotations

import re
from pathlib import Path

import casadi as ca
import numpy as np

from flexarm import control_law as law
from flexarm import filter_design, filter_law, sensor_law
from flexarm.law_ops import as_written
from flexarm.parameters import N_ELEMENTS

from . import native_codegen
from .native_codegen import check_no_library_math, drop_null_checks  # the plant's checks, the same

#: The measurements (q1, q2, q̇1, q̇2, ε1..ε6) and the state (11 angles, 11 rates).
N_MEAS, N_STATE = 10, 22
#: Room for the payload bank's filters in the native controller (its resource says how many: 9); the bank's
#: weighted sums are generated for this many, the unused ones weighted 0. The C's MAX_FILTERS is this.
BANK_FILTERS = 12


def _symbols(name: str, shape: tuple[int, ...]) -> tuple[ca.SX, np.ndarray]:
    """A CasADi input of prod(shape) elements and the same symbols as a row-major object array."""
    sym, elements = native_codegen._symbols(name, int(np.prod(shape)))
    return sym, elements.reshape(shape)


def _output(a) -> ca.SX:
    return ca.vertcat(*np.ravel(np.asarray(a, dtype=object)))


def law_functions() -> list[ca.Function]:
    """The law's CasADi functions, each built by calling :mod:`flexarm.control_law` on symbols."""
    k_sx, k = _symbols("gain", (2, N_STATE))
    e_sx, e = _symbols("estimator", (N_STATE, N_MEAS))
    md_sx, md = _symbols("desired_measurements", (N_MEAS,))
    ff_sx, ff = _symbols("feedforward", (2,))
    corr_sx, corr = _symbols("correction", (2,))
    ke_sx, ke = _symbols("gain_on_measurements", (2, N_MEAS))
    m_sx, m = _symbols("measurements", (N_MEAS,))
    off_sx, off = _symbols("offset", (2,))
    lim_sx, lim = _symbols("limit", (2,))
    ts_sx, ts = _symbols("switch_time", (1,))
    t_sx, t = _symbols("t", (1,))
    x_hat_d = law.reconstructed_states(md[None, :], e)  # (1, 22)
    return [
        ca.Function("generated_gain_on_measurements", [k_sx, e_sx], [_output(law.gain_on_measurements(k, e))],
                    ["gain", "estimator"], ["gain_on_measurements"]),
        ca.Function("generated_gain_offset", [k_sx, e_sx, md_sx], [_output(law.gain_offsets(k[None], x_hat_d))],
                    ["gain", "estimator", "desired_measurements"], ["offset"]),
        ca.Function("generated_tracking_torque", [ff_sx, ke_sx, m_sx, off_sx, lim_sx],
                    [_output(law.tracking_torque(ff, ke, m, off, lim))],
                    ["feedforward", "gain_on_measurements", "measurements", "offset", "limit"], ["torque"]),
        ca.Function("generated_corrected_feedforward", [ff_sx, corr_sx],
                    [_output(law.corrected_feedforward(ff, corr))], ["feedforward", "correction"], ["command"]),
        ca.Function("generated_saturate", [ff_sx, lim_sx], [_output(law.saturate(ff, lim))], ["torque", "limit"],
                    ["saturated"]),
        ca.Function("generated_has_switched", [ts_sx, t_sx], [law.has_switched(ts[0], t[0])],
                    ["switch_time", "t"], ["switched"]),
    ]


def filter_law_functions() -> list[ca.Function]:
    """The LQG's CasADi functions (Kalman filter, predictor, feedback), each built by calling
    :mod:`flexarm.filter_law` on symbols."""
    phi_sx, phi = _symbols("phi", (N_STATE, N_STATE))
    gam_sx, gam = _symbols("gamma", (N_STATE, 2))
    x_sx, x = _symbols("x", (N_STATE,))
    du_sx, du = _symbols("du", (2,))
    m_gain_sx, m_gain = _symbols("filter_gain", (N_STATE, N_MEAS))
    c_sx, c = _symbols("c", (N_MEAS, N_STATE))
    m_sx, m = _symbols("measurements", (N_MEAS,))
    md_sx, md = _symbols("desired", (N_MEAS,))
    cmd_sx, cmd = _symbols("command", (2,))
    k_sx, k = _symbols("gain", (2, N_STATE))
    kxi_sx, kxi = _symbols("gain_integral", (2, 2))
    xi_sx, xi = _symbols("xi", (2,))
    dt_sx, dt = _symbols("dt", (1,))
    cq_sx, cq = _symbols("c_q", (2, N_STATE))
    tau_sx, tau = _symbols("tau", (2,))
    free_sx, free = _symbols("tau_free", (2,))
    # one time update, with the drift: the single filter passes a zero drift, which changes no bit (its compensated
    # sums start from +0.0, so they are never -0.0, and x + 0.0 = x for every other x); one copy of the largest
    # function (22 x 24 compensated products) instead of two
    drift_sx, drift = _symbols("drift", (N_STATE,))
    e_sx, e = _symbols("innovation", (N_MEAS,))
    lp_sx, lp = _symbols("log_p", (1,))
    si_sx, si = _symbols("s_inv", (N_MEAS, N_MEAS))
    ld_sx, ld = _symbols("log_det_s", (1,))
    w_sx, w = _symbols("weights", (BANK_FILTERS,))
    u_sx, u = _symbols("feedbacks", (BANK_FILTERS, 2))
    xs_sx, xs = _symbols("estimates", (BANK_FILTERS, N_STATE))
    lps_sx, lps = _symbols("log_p", (BANK_FILTERS,))
    act_sx, act = _symbols("active", (BANK_FILTERS,))
    floor_sx, floor = _symbols("log_floor", (1,))
    posterior = filter_law.normalised_posterior(lps, floor, act)
    psi_sx, psi = _symbols("psi", (N_STATE, N_ELEMENTS))
    da_sx, da = _symbols("delta_acceleration", (N_ELEMENTS,))
    p0_sx, p0 = _symbols("p_unloaded", (1,))
    rb_sx, rb = _symbols("reseed_below", (1,))
    xu_sx, xu = _symbols("x_unloaded", (N_STATE,))
    return [
        ca.Function("generated_time_update_drift", [phi_sx, gam_sx, x_sx, du_sx, drift_sx],
                    [_output(filter_law.time_update(phi, gam, x, du, drift))], ["phi", "gamma", "x", "du", "drift"],
                    ["next"]),
        ca.Function("generated_innovation", [x_sx, c_sx, m_sx, md_sx], [_output(filter_law.innovation(x, c, m, md))],
                    ["x", "c", "measurements", "desired"], ["innovation"]),
        ca.Function("generated_updated", [x_sx, m_gain_sx, e_sx], [_output(filter_law.updated(x, m_gain, e))],
                    ["x", "filter_gain", "innovation"], ["posterior"]),
        ca.Function("generated_log_likelihood_update", [lp_sx, e_sx, si_sx, ld_sx],
                    [_output(filter_law.log_likelihood_update(lp, e, si, ld))],
                    ["log_p", "innovation", "s_inv", "log_det_s"], ["next_log_p"]),
        ca.Function("generated_feedback", [k_sx, x_sx], [_output(filter_law.feedback(k, x))], ["gain", "x"],
                    ["feedback"]),
        ca.Function("generated_feedback_integral", [k_sx, x_sx, kxi_sx, xi_sx],
                    [_output(filter_law.feedback(k, x, kxi, xi))], ["gain", "x", "gain_integral", "xi"],
                    ["feedback"]),
        ca.Function("generated_bank_free_torque", [cmd_sx, w_sx, u_sx],
                    [_output(filter_law.bank_free_torque(cmd, w, u))], ["command", "weights", "feedbacks"],
                    ["tau_free"]),
        ca.Function("generated_weighted_estimate", [w_sx, xs_sx], [_output(filter_law.weighted_estimate(w, xs))],
                    ["weights", "estimates"], ["estimate"]),
        ca.Function("generated_normalised_posterior", [lps_sx, act_sx, floor_sx],
                    [_output(posterior[0]), _output(posterior[1])], ["log_p", "active", "log_floor"],
                    ["normalised_log_p", "p"]),
        ca.Function("generated_state_drift", [psi_sx, da_sx], [_output(filter_law.state_drift(psi, da))],
                    ["psi", "delta_acceleration"], ["drift"]),
        ca.Function("generated_reseeded", [p0_sx, rb_sx, x_sx, xu_sx],
                    [_output(filter_law.reseeded(p0[0], rb[0], x, xu))],
                    ["p_unloaded", "reseed_below", "x_quiet", "x_unloaded"], ["x"]),
        ca.Function("generated_measured", [c_sx, x_sx], [_output(filter_law.measured(c, x))], ["c", "x"],
                    ["deviation"]),
        ca.Function("generated_free_torque", [cmd_sx, k_sx, x_sx], [_output(filter_law.free_torque(cmd, k, x))],
                    ["command", "gain", "x"], ["tau_free"]),
        ca.Function("generated_free_torque_integral", [cmd_sx, k_sx, x_sx, kxi_sx, xi_sx],
                    [_output(filter_law.free_torque(cmd, k, x, kxi, xi))],
                    ["command", "gain", "x", "gain_integral", "xi"], ["tau_free"]),
        ca.Function("generated_integrated", [xi_sx, dt_sx, cq_sx, x_sx, tau_sx, free_sx],
                    [_output(filter_law.integrated(xi, dt, cq, x, tau, free))],
                    ["xi", "dt", "c_q", "x", "tau", "tau_free"], ["next_xi"]),
    ]


def covariance_step_function() -> ca.Function:
    """:func:`flexarm.filter_law.covariance_step` on CasADi MX matrices: the predictor's time-varying filter at
    instantiation, 2058 samples of 22×22 products, as loops (SX would unroll them into megabytes of C). The C's
    buffers are row-major, CasADi's column-major: each input is read as its transpose and each output written as
    one."""
    p_t = ca.MX.sym("p", N_STATE, N_STATE)
    c_t = ca.MX.sym("c", N_STATE, N_MEAS)
    v_t = ca.MX.sym("v", N_MEAS, N_MEAS)
    phi_t = ca.MX.sym("phi", N_STATE, N_STATE)
    w_t = ca.MX.sym("w", N_STATE, N_STATE)
    gain, p_next = filter_law.covariance_step(p_t.T, c_t.T, v_t.T, phi_t.T, w_t.T)
    return ca.Function("generated_covariance_step", [p_t, c_t, v_t, phi_t, w_t], [gain.T, p_next.T],
                       ["p", "c", "measurement_noise", "phi", "process_noise"], ["gain", "p_next"])


def sensor_law_functions() -> list[ca.Function]:
    """The sensors' CasADi functions, each built by calling :mod:`flexarm.sensor_law` on one channel's symbols."""
    sos_sx, sos = _symbols("sos", (6,))
    s0_sx, s0 = _symbols("state0", (1,))
    s1_sx, s1 = _symbols("state1", (1,))
    x_sx, x = _symbols("x", (1,))
    u_sx, u = _symbols("uniform", (1,))
    a_sx, a = _symbols("amplitude", (1,))
    lsb_sx, lsb = _symbols("lsb", (1,))
    lo_sx, lo = _symbols("lo_code", (1,))
    hi_sx, hi = _symbols("hi_code", (1,))
    zi_sx, zi = _symbols("unit_state", (2,))
    y, n0, n1 = sensor_law.filter_section(sos, s0, s1, x)
    return [
        ca.Function("generated_filter_section", [sos_sx, s0_sx, s1_sx, x_sx], [_output(y), _output(n0), _output(n1)],
                    ["sos", "state0", "state1", "x"], ["y", "next0", "next1"]),
        ca.Function("generated_primed_state", [zi_sx, x_sx], [_output(sensor_law.primed_state(zi, x))],
                    ["unit_state", "x"], ["state"]),
        ca.Function("generated_with_noise", [x_sx, a_sx, u_sx], [_output(sensor_law.with_noise(x, a, u))],
                    ["y", "amplitude", "uniform"], ["noisy"]),
        ca.Function("generated_quantize", [x_sx, lsb_sx, lo_sx, hi_sx],
                    [_output(sensor_law.quantize(x, lsb, lo, hi))], ["x", "lsb", "lo_code", "hi_code"],
                    ["quantized"]),
        channel_scales_function(),
        *butterworth_functions(),
    ]


def channel_scales_function() -> ca.Function:
    """:func:`flexarm.sensor_law.channel_scales`: each channel's noise half-width and quantum at initialisation."""
    names = ["encoder_noise_deg", "tachometer_noise_deg_per_s", "strain_gauge_noise_deg",
             "accelerometer_noise_m_per_s2", "encoder_counts_per_rev", "tachometer_full_scale_deg_per_s",
             "gauge_full_scale_curvature_per_m", "segment_lengths", "accelerometer_full_scale_m_per_s2", "adc_codes"]
    shapes = {"gauge_full_scale_curvature_per_m": (2,), "segment_lengths": (6,)}
    inputs = [_symbols(name, shapes.get(name, (1,))) for name in names]
    args = [elements if name in shapes else elements[0] for name, (_, elements) in zip(names, inputs)]
    with as_written():  # as the numbers path rounds (no rewriting of its quotients)
        outputs = sensor_law.channel_scales(*args)
    return ca.Function("generated_channel_scales", [sym for sym, _ in inputs], [_output(o) for o in outputs], names,
                       ["amplitude", "encoder_lsb", "full_scale", "adc_lsb", "lo_code", "hi_code"])


def butterworth_functions() -> list[ca.Function]:
    """The filter design of :mod:`flexarm.filter_design`: the tangent's argument, and one function per order."""
    c_sx, c = _symbols("cutoff_hz", (1,))
    fs_sx, fs = _symbols("sample_rate_hz", (1,))
    t_sx, t = _symbols("tan_prewarp", (1,))
    functions = [ca.Function("generated_prewarp_argument", [c_sx, fs_sx],
                             [_output(filter_design.prewarp_argument(c[0], fs[0]))],
                             ["cutoff_hz", "sample_rate_hz"], ["argument"])]
    for order in filter_design.ORDERS:
        sos, unit_state = filter_design.butterworth_sections(order, t[0])
        functions.append(ca.Function(f"generated_butterworth_order_{order}", [t_sx],
                                     [_output(sos), _output(unit_state)], ["tan_prewarp"], ["sos", "unit_state"]))
    return functions


def _api(functions: list[ca.Function], stem: str, source: str, defines: tuple[str, ...] = ()) -> str:
    """<stem>_api.h: one plain C function per generated one (arguments and results as pointers)."""
    guard = f"{stem.upper()}_API_H"
    lines = [f"/* GENERATED by fmu_build/law_codegen.py from {source}: do not edit. */",
             f"#ifndef {guard}", f"#define {guard}", f'#include "{stem}.h"', "", *defines, ""]
    for f in functions:
        name = f.name()
        ins = [f.name_in(i) for i in range(f.n_in())]
        outs = [f.name_out(i) for i in range(f.n_out())]
        params = [f"const double *{a}" for a in ins] + [f"double *out_{o}" for o in outs]
        lines += [f"static inline void {name.replace('generated_', 'law_', 1)}({', '.join(params)})", "{",
                  f"    const double *arg[{max(len(ins), 1)}] = {{{', '.join(ins)}}};",
                  f"    double *res[{max(len(outs), 1)}] = {{{', '.join('out_' + o for o in outs)}}};",
                  f"    long long iw[{max(f.sz_iw(), 1)}];",
                  f"    double w[{max(f.sz_w(), 1)}];",
                  f"    {name}(arg, res, iw, w, 0);", "}", ""]
    return "\n".join(lines + ["#endif", ""])


def _generate(out_dir: Path, stem: str, source: str, functions: list[ca.Function],
              defines: tuple[str, ...] = ()) -> list[Path]:
    gen = ca.CodeGenerator(f"{stem}.c", {"with_header": True, "casadi_real": "double", "casadi_int": "long long",
                                         "with_export": False})
    for f in functions:
        gen.add(f)
    gen.generate(str(out_dir) + "/")
    _route_portable(out_dir / f"{stem}.c")
    check_no_library_math(out_dir / f"{stem}.c")
    drop_null_checks(out_dir / f"{stem}.c")
    _route_libm(out_dir / f"{stem}.c")
    (out_dir / f"{stem}_api.h").write_text(_api(functions, stem, source, defines))
    return [out_dir / f"{stem}{suffix}" for suffix in (".c", ".h", "_api.h")]


def _route_portable(path: Path) -> None:
    """The laws' exp and log1p (the bank's posterior, :func:`flexarm.law_ops.log_sum_exp`) call the portable ones
    (``portable_math.h``, the hand C's before), whose bits are the same on every platform; C libraries' differ."""
    text = path.read_text()
    routed, n = re.subn(r"\b(exp|log1p)\(", r"flexarm_\1(", text)
    routed = routed.replace("return log(1+x);", "return flexarm_log1p(x);")  # casadi_log1p's pre-C99 branch
    if n:
        if "#include <math.h>\n" not in routed:
            raise RuntimeError(f"{path}: CasADi's code no longer includes <math.h>: update _route_portable")
        routed = routed.replace("#include <math.h>\n", '#include <math.h>\n#include "portable_math.h"\n', 1)
    path.write_text(routed)


def _route_libm(path: Path) -> None:
    """CasADi's C calls fmax, fmin, remainder and copysign, which live in libm on Linux: include libm_link.h
    (every model source does), so a binary built without libm (FMPy's ``fmpy compile``) still loads."""
    text = path.read_text()
    if "#include <math.h>\n" not in text:
        raise RuntimeError(f"{path}: CasADi's code no longer includes <math.h>: update _route_libm")
    path.write_text(text.replace("#include <math.h>\n", '#include <math.h>\n#include "libm_link.h"\n', 1))


def generate_control_law(out_dir: Path) -> list[Path]:
    """Write control_law.c, .h and _api.h (:func:`law_functions`) into `out_dir`; return their paths."""
    return _generate(out_dir, "control_law", "flexarm/control_law.py and flexarm/filter_law.py",
                     law_functions() + filter_law_functions() + [covariance_step_function()],
                     (f"#define LAW_BANK_FILTERS {BANK_FILTERS} /* the bank's weighted sums' length */",))


def generate_sensor_law(out_dir: Path) -> list[Path]:
    """Write sensor_law.c, .h and _api.h (:func:`sensor_law_functions`) into `out_dir`; return their paths."""
    return _generate(out_dir, "sensor_law", "flexarm/sensor_law.py and flexarm/filter_design.py",
                     sensor_law_functions(),
                     (f"#define LAW_BUTTERWORTH_ORDERS {filter_design.ORDERS[-1]} /* law_butterworth_order_1.. */",))
