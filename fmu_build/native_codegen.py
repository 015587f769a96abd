"""Generate the native plant's physics C and its resource file from the flexarm model (build time).

The C is CasADi's code generation of the very kernels the Python plant runs:
the NumPy path of :mod:`flexarm._kernels` (``assemble``, ``tangent_matrices``)
evaluated on CasADi SX symbols instead of numbers, so there is no second copy
of the equations (eq. 1, 5, 8 and the appendix gradients). cos θ and sin θ are
inputs (the C computes them once per state, with the FMU's own portable sin/cos,
and shares them between these functions and the kinematics); the factorisation
of M(θ) and the n = 11 solves are generated too, as straight-line code (see
:func:`generate_physics`).

``coeff`` is (M_jk row-major, the non-zero entries of the stiffness matrix
row-major): the arm's constants are not compiled in but read from
``arm_parameters.txt``, a resource of the FMU holding IEEE-754 bit patterns
(exact on every platform).
"""

from __future__ import annotations

import re
import struct
from pathlib import Path

import casadi as ca
import numpy as np

from flexarm.integrator import EXPONENTIAL_HORIZON_S
from flexarm.model import DAMPING_CONFIGURATION, ArmModel, numpy_kernels
from flexarm.parameters import (
    JOINT2_PAIR,
    LINK1_TIP_ELEMENT,
    LINK2_TIP_ELEMENT,
    N_ELEMENTS,
    STRAIN_GAUGE_ELEMENTS,
    ArmParameters,
    load_parameters,
)
from flexarm.substeps import REFERENCE_STEPS_PER_SUBSTEP

#: The resource file of the plant FMU.
ARM_RESOURCE = "arm_parameters.txt"
#: The resource file of the sensors FMU.
SENSOR_RESOURCE = "sensor_constants.txt"


def _numpy_kernels():
    """flexarm._kernels on its NumPy path (the one that accepts symbolic arrays)."""
    return numpy_kernels()


def _stiffness_pattern(model: ArmModel) -> np.ndarray:
    return model.stiffness != 0.0


def _symbols(name: str, n: int) -> tuple[ca.SX, np.ndarray]:
    sym = ca.SX.sym(name, n)
    return sym, np.array([sym[i] for i in range(n)], dtype=object)


class _Angle:
    """A symbolic angle whose cosine and sine are given symbols: NumPy's np.cos/np.sin on an object array call
    these methods, so the kernels take cos θ and sin θ as inputs (computed once per state in C, shared by the
    generated functions and the kinematics) instead of calling the trigonometric functions themselves."""

    def __init__(self, cos, sin):
        self._cos, self._sin = cos, sin

    def cos(self):
        return self._cos

    def sin(self):
        return self._sin


def lower_packed(n: int) -> list[tuple[int, int]]:
    """(row, column) of the lower triangle of an n×n matrix, column by column: the packed order of M(θ)."""
    return [(i, j) for j in range(n) for i in range(j, n)]


def _ldl(packed: list, n: int) -> tuple[list, list, list]:
    """M = L D Lᵀ of the symmetric matrix whose lower triangle is `packed` (:func:`lower_packed` order), on symbols.

    Straight-line code for the n = 11 factorisation that runs twelve times per 1 ms step: the compiler schedules
    independent elements side by side (a loop keeps them in memory, on one long chain). No square roots.
    Returns L's strict lower triangle (column by column), 1/d_j and d_j (the C checks d_j > 0: positive definite).
    """
    a = {ij: x for ij, x in zip(lower_packed(n), packed)}
    low, d, dinv = {}, [], []
    for j in range(n):
        w = [low[j, k] * d[k] for k in range(j)]
        col = {}
        for i in range(j, n):
            t = a[i, j]
            for k in range(j):
                t = t - low[i, k] * w[k]
            col[i] = t
        d.append(col[j])
        dinv.append(1.0 / col[j])
        for i in range(j + 1, n):
            low[i, j] = col[i] * dinv[j]
    return [low[i, j] for j in range(n) for i in range(j + 1, n)], dinv, d


def _ldl_solve_function(n: int) -> ca.Function:
    """``flexarm_ldl_solve(L, 1/d, b) -> x`` = (L D Lᵀ)⁻¹ b with :func:`_ldl`'s factors, straight-line."""
    low_sx, low_v = _symbols("unit_lower", n * (n - 1) // 2)
    dinv_sx, dinv = _symbols("inverse_pivots", n)
    b_sx, b = _symbols("b", n)
    low = dict(zip([(i, j) for j in range(n) for i in range(j + 1, n)], low_v))
    y = list(b)
    for i in range(n):  # L y = b
        for k in range(i):
            y[i] = y[i] - low[i, k] * y[k]
    y = [y[i] * dinv[i] for i in range(n)]
    x = [None] * n
    for i in reversed(range(n)):  # Lᵀ x = D⁻¹ y, the newest x_k last
        t = y[i]
        for k in reversed(range(i + 1, n)):
            t = t - low[k, i] * x[k]
        x[i] = t
    return ca.Function("flexarm_ldl_solve", [low_sx, dinv_sx, b_sx], [ca.vertcat(*x)])


def _lu_solve_function(n: int) -> ca.Function:
    """``flexarm_lu_solve(LU, b_permuted) -> x``: LU row-major with 1/U_ii on the diagonal (plant_linalg.h
    lu_factor), b already permuted by its pivots; straight-line."""
    lu_sx, lu_v = _symbols("lu", n * n)
    b_sx, b = _symbols("b", n)
    lu = np.asarray(lu_v, dtype=object).reshape(n, n)
    x = list(b)
    for k in range(n):  # unit lower, k ascending
        for i in range(k + 1, n):
            x[i] = x[i] - lu[i, k] * x[k]
    for i in reversed(range(n)):
        t = x[i]
        for k in reversed(range(i + 1, n)):
            t = t - lu[i, k] * x[k]
        x[i] = t * lu[i, i]
    return ca.Function("flexarm_lu_solve", [lu_sx, b_sx], [ca.vertcat(*x)])


def generate_physics(out_dir: Path, params: ArmParameters | None = None) -> list[Path]:
    """Write flexarm_physics.c/.h (CasADi) and plant_constants.h into `out_dir`; return the paths.

    Generated functions (cos θ and sin θ are inputs; ``coeff`` = (M_jk row-major, stiffness non-zeros)):

    * ``flexarm_mass_rhs(cos θ, sin θ, θ̇, coeff) -> (M(θ)'s lower triangle packed column by column, S(θ, θ̇),
      L, 1/d, d)`` with M = L D Lᵀ (:func:`_ldl`; the C checks d > 0);
    * ``flexarm_tangents(cos θ, sin θ, θ̇, θ̈, coeff) -> (Q, V)`` column-major, Q = ∂(S − Mθ̈)/∂θ at fixed θ̈,
      V = ∂S/∂θ̇;
    * ``flexarm_input_forces(τ) -> B̄τ``;
    * ``flexarm_ldl_solve(L, 1/d, b) -> M⁻¹ b`` and ``flexarm_lu_solve(LU, b permuted) -> W⁻¹ b`` (RODAS4's stage
      matrix W, factored by plant_linalg.h).
    """
    model = ArmModel(params if params is not None else load_parameters())
    kern = _numpy_kernels()
    n = N_ELEMENTS
    pattern = _stiffness_pattern(model)
    n_k = int(pattern.sum())
    cos_sx, cos = _symbols("cos_theta", n)
    sin_sx, sin = _symbols("sin_theta", n)
    om_sx, om = _symbols("omega", n)
    acc_sx, acc = _symbols("acc", n)
    tau_sx, tau = _symbols("tau", 2)
    coeff_sx, coeff = _symbols("coeff", n * n + n_k)
    th = np.array([_Angle(c, s) for c, s in zip(cos, sin)], dtype=object)
    mc = coeff[: n * n].reshape(n, n)
    kl = np.zeros((n, n), dtype=object)
    kl[pattern] = coeff[n * n:]
    kl[~pattern] = 0.0
    mass, rhs, cosd, sind = kern.assemble(th, om, mc, kl)
    q, v = kern.tangent_matrices(mc, kl, cosd, sind, om, acc)
    forces = model.input_matrix() @ tau  # B̄τ

    def sx(a):
        a = np.asarray(a, dtype=object)
        return ca.vertcat(*[ca.horzcat(*row) for row in a]) if a.ndim == 2 else ca.vertcat(*a)

    mass_lower = [mass[i, j] for i, j in lower_packed(n)]
    low, dinv, piv = _ldl(mass_lower, n)
    f_mass = ca.Function("flexarm_mass_rhs", [cos_sx, sin_sx, om_sx, coeff_sx],
                         [sx(mass_lower), sx(rhs), sx(low), sx(dinv), sx(piv)])
    f_tan = ca.Function("flexarm_tangents", [cos_sx, sin_sx, om_sx, acc_sx, coeff_sx], [sx(q), sx(v)])
    f_in = ca.Function("flexarm_input_forces", [tau_sx], [sx(forces)])
    functions = (f_mass, f_tan, f_in, _ldl_solve_function(n), _lu_solve_function(n))
    gen = ca.CodeGenerator("flexarm_physics.c", {"with_header": True, "casadi_real": "double",
                                                 "casadi_int": "long long", "with_export": False})
    for f in functions:
        gen.add(f)
    gen.generate(str(out_dir) + "/")
    check_no_library_math(out_dir / "flexarm_physics.c")
    drop_null_checks(out_dir / "flexarm_physics.c")
    work = max(f.sz_w() for f in functions)
    iwork = max(f.sz_iw() for f in functions)
    a_rows = ",\n    ".join("{" + ", ".join(repr(float(x)) for x in row) + "}" for row in kern.RODAS4_A)
    c_rows = ",\n    ".join("{" + ", ".join(repr(float(x)) for x in row) + "}" for row in kern.RODAS4_C)
    pade = ", ".join(repr(float(x)) for x in kern._PADE13)

    def rows(a):
        return ", ".join("{" + ", ".join(repr(float(x)) for x in row) + "}" for row in a)

    gauss_a, gauss_a2 = rows(kern.GAUSS_A), rows(kern.GAUSS_A2)
    gauss_c = ", ".join(repr(float(x)) for x in kern.GAUSS_C)
    constants = f"""/* GENERATED by fmu_build/native_codegen.py from flexarm (parameters, _kernels): do not edit. */
#ifndef PLANT_CONSTANTS_H
#define PLANT_CONSTANTS_H
#define PLANT_N_ELEMENTS {n}
#define PLANT_N_SPRING_VALUES {n_k}
#define PLANT_N_MASS_PACKED {len(mass_lower)}
#define PLANT_N_UNIT_LOWER {len(low)}
#define PLANT_WORK_DOUBLES {max(work, 1)}
#define PLANT_WORK_INTS {max(iwork, 1)}
#define PLANT_JOINT2_PROXIMAL {JOINT2_PAIR[0]}
#define PLANT_JOINT2_DISTAL {JOINT2_PAIR[1]}
#define PLANT_LINK1_TIP {LINK1_TIP_ELEMENT}
#define PLANT_LINK2_TIP {LINK2_TIP_ELEMENT}
#define PLANT_STRAIN_GAUGE_ELEMENTS {{{", ".join(str(e) for e in STRAIN_GAUGE_ELEMENTS)}}}
/* joint angles (rad) at which flexarm.model.modal_damping_matrix builds C_d */
#define PLANT_DAMPING_Q1 {float(DAMPING_CONFIGURATION[0])!r}
#define PLANT_DAMPING_Q2 {float(DAMPING_CONFIGURATION[1])!r}
/* RODAS4 (flexarm._kernels) */
#define RODAS4_GAMMA {kern.RODAS4_GAMMA!r}
static const double RODAS4_A[5][4] = {{
    {a_rows}}};
static const double RODAS4_C[6][5] = {{
    {c_rows}}};
/* its error control: largest embedded estimate on an angle (rad), most halvings of the nominal substep */
#define RODAS4_ANGLE_TOL {kern.RODAS4_ANGLE_TOL!r}
#define RODAS4_MAX_HALVINGS {kern.RODAS4_MAX_HALVINGS}
/* 2-stage Gauss-Legendre (flexarm._kernels.GAUSS_*) and its simplified-Newton tolerances */
static const double GAUSS_A[2][2] = {{{gauss_a}}};
static const double GAUSS_A2[2][2] = {{{gauss_a2}}};
static const double GAUSS_C[2] = {{{gauss_c}}};
#define GAUSS_TOL {kern.GAUSS_TOL!r}
#define GAUSS_FLOOR {kern.GAUSS_FLOOR!r}
#define GAUSS_MAX_ITER {kern.GAUSS_MAX_ITER}
/* flexarm.integrator: RK4 steps per substep of the reference, the exponential scheme's horizon (s) */
#define PLANT_REFERENCE_STEPS_PER_SUBSTEP {REFERENCE_STEPS_PER_SUBSTEP}
#define PLANT_EXPONENTIAL_HORIZON_S {EXPONENTIAL_HORIZON_S!r}
/* Exponential Rosenbrock-Euler's matrix exponential (flexarm._kernels.expm): Pade [13/13] coefficients, theta_13 */
static const double EXPM_PADE13[14] = {{{pade}}};
#define EXPM_THETA13 {kern._THETA13!r}
#endif
"""
    (out_dir / "plant_constants.h").write_text(constants)
    return [out_dir / "flexarm_physics.c", out_dir / "flexarm_physics.h", out_dir / "plant_constants.h"]


def check_no_library_math(path: Path) -> None:
    """The generated C must call no C-library function whose last bit differs between platforms."""
    calls = sorted(set(re.findall(r"\b(sin|cos|tan|exp|log|pow|atan2?|sqrt|fabs)\(", path.read_text())))
    if calls:
        raise RuntimeError(f"{path}: CasADi's code calls {calls}: the physics must take cos θ and sin θ as inputs")


def drop_null_checks(path: Path) -> None:
    """CasADi's code tests every argument and result pointer for NULL at every use; plant.c always passes all of
    them, and the tests cost about 7 % of a step (they keep values out of registers)."""
    text = path.read_text()
    text, n_args = re.subn(r"arg\[(\d+)\]\? arg\[\1\]\[(\d+)\] : 0", r"arg[\1][\2]", text)
    text, n_res = re.subn(r"if \(res\[(\d+)\]!=0\) ", "", text)
    if not (n_args and n_res) or re.search(r"arg\[\d+\]\?|res\[\d+\]!=0", text):
        raise RuntimeError(f"{path}: CasADi's NULL tests changed form ({n_args}, {n_res} replaced): update "
                           "drop_null_checks")
    path.write_text(text)


def hex_doubles(values) -> str:
    """IEEE-754 bit patterns of `values`, 16 hex digits each (read back exactly by the C glue)."""
    return " ".join(struct.pack(">d", float(x)).hex() for x in np.ravel(values))


def write_resource(path: Path, entries: dict[str, np.ndarray], header: str) -> None:
    """A resource file: comment lines, then per entry ``name count`` and the bit patterns (8 per line)."""
    lines = [f"# {line}" for line in header.splitlines()]
    for name, values in entries.items():
        flat = np.ravel(np.asarray(values, dtype=float))
        lines.append(f"{name} {flat.size}")
        lines += [hex_doubles(flat[i:i + 8]) for i in range(0, flat.size, 8)]
    path.write_text("\n".join(lines) + "\n")


def write_arm_resource(path: Path, params: ArmParameters | None = None) -> None:
    """The plant's constants, split so that the payload and the links' stiffness stay parameters.

    M_jk is affine in the tip payload p: M(p) = M(0) + p (M(1) − M(0)). The stiffness non-zeros are those of the
    brackets' springs plus ``link_stiffness_scale`` times those of the links' springs, the sum
    :meth:`flexarm.parameters.ArmParameters.stiffness_matrix` forms (the same bits).
    """
    params = params if params is not None else load_parameters()
    base = ArmModel(params.with_payload(0.0))
    per_kg = ArmModel(params.with_payload(1.0)).mass_coefficients - base.mass_coefficients
    pattern = _stiffness_pattern(base)
    brackets, links = params.stiffness_parts()
    write_resource(path, {
        "mass_coefficients_no_payload": base.mass_coefficients,
        "mass_coefficients_per_kg_payload": per_kg,
        "spring_stiffness_brackets": brackets[pattern],
        "spring_stiffness_links": links[pattern],
        "length": params.length,
    }, f"flexarm arm constants for the native plant FMU (IEEE-754 doubles as hex bit patterns)\n"
       f"source: {Path(params.source).name} sha256 {params.sha256}")


def write_sensor_resource(path: Path, params: ArmParameters | None = None) -> None:
    """The sensors' arm constants: the gauged segments' lengths (angle = curvature x length)."""
    from flexarm.sensors import strain_gauge_segment_lengths

    params = params if params is not None else load_parameters()
    write_resource(path, {"strain_gauge_segment_lengths": strain_gauge_segment_lengths(params)},
                   f"flexarm sensor constants for the native sensors FMU (IEEE-754 doubles as hex bit patterns)\n"
                   f"source: {Path(params.source).name} sha256 {params.sha256}")


#: The controller FMUs' resource files.
TRAJECTORY_RESOURCE = "trajectory.txt"
GAINS_RESOURCE = "gains.txt"
#: ``gain_set`` enumeration values (docs/fmu-interface.md, type GainSet) -> flexarm.lqr weight names.
GAIN_SETS = {1: "gamma1", 2: "gamma0.1", 3: "gamma0", 4: "eq32"}
#: ``omega7_estimate`` enumeration values (type Omega7Estimate) -> flexarm.lqr.OMEGA7_CHOICES.
OMEGA7_ESTIMATES = {1: "tachometer", 2: "rigid"}


def write_trajectory_resource(path: Path, trajectory_file: Path | None = None) -> None:
    """The trajectory as the control law uses it: feedforward torques and the desired measurements.

    Desired measurements m_d = (q1, q2, q̇1, q̇2, ε1..ε6) of every sample, from the desired state
    through the sensor map (flexarm.control: "like with like"), and the estimator matrices E
    (x̂ = E m) of both ``omega7_estimate`` choices. `trajectory_file`: default the committed one (a payload data
    folder's, :mod:`flexarm.payload_data`, for a controller on a re-planned slew).
    """
    from flexarm import control
    from flexarm.model import joint_angles, joint_velocities, strain_gauge_angles
    from flexarm.provenance import sha256_file
    from flexarm.trajectory import DEFAULT_TRAJECTORY_FILE, load_trajectory

    source = DEFAULT_TRAJECTORY_FILE if trajectory_file is None else Path(trajectory_file)
    traj = load_trajectory(source)
    th, om = traj.theta, traj.omega
    m_d = np.column_stack([np.array([joint_angles(t) for t in th]), np.array([joint_velocities(o) for o in om]),
                           np.array([strain_gauge_angles(t) for t in th])])
    entries = {"n_steps": [len(traj.t) - 1], "dt": [float(traj.t[1] - traj.t[0])], "feedforward_torque": traj.tau,
               "desired_measurements": m_d}
    for value, choice in OMEGA7_ESTIMATES.items():
        entries[f"estimator_{value}"] = control._estimator_matrix(choice)
    write_resource(path, entries, f"flexarm trajectory for the native controller FMUs (IEEE-754 hex bit patterns)\n"
                                  f"source: {source.name} sha256 {sha256_file(source)}\n"
                                  f"estimator_<v>: omega7_estimate = v ({OMEGA7_ESTIMATES})")


def write_gains_resource(path: Path, discrete: bool, gains_dir: Path | None = None) -> None:
    """Every gain schedule of the four weight sets (``dlqr-`` designs if `discrete`), reduced gains (2, 22), from
    `gains_dir` (default the committed ``flexarm/data/gains``)."""
    from flexarm.lqr import SCHEDULES, GainSchedule

    entries, names = {}, []
    for value, weights in GAIN_SETS.items():
        name = f"dlqr-{weights}" if discrete else weights
        for label in SCHEDULES:
            sched = GainSchedule.load(name, label, directory=gains_dir)
            entries[f"set{value}_{label}_count"] = [len(sched.times)]
            entries[f"set{value}_{label}_times"] = sched.times
            entries[f"set{value}_{label}_gains"] = sched.reduced_gains()
            names.append(f"set{value}_{label} = {name}_{label}")
    write_resource(path, entries, "flexarm reduced LQR gains for the native controller FMUs (IEEE-754 hex bit "
                                  "patterns)\n" + "\n".join(names))
