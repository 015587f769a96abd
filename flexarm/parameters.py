"""Physical parameters of the 11-element arm: build, load and write them.

Two files live in ``flexarm/data``:

``sandia_arm_design.toml``
    What the paper states, what we chose where it is silent, and the
    calibration targets and unknowns.
``sandia_arm.toml``
    The complete parameter set (every element, spring and point mass, each
    value tagged ``paper``, ``derived``, ``chosen`` or ``calibrated``). It is
    written by ``python -m flexarm.calibration`` and read by everything else.

Element numbering follows the paper (1-based in files and documents,
0-based in arrays):

====  ==============================================
 1    hub of joint 1 (motor-1 rotor)
 2    bracket 1
 3-5  link 1, three equal segments
 6    bracket 2, carrying the elbow motor's stator
 7    joint 2 (motor-2 rotor)
 8    bracket 3
 9-11 link 2, three equal segments
====  ==============================================
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

N_ELEMENTS = 11
DATA_DIR = Path(__file__).resolve().parent / "data"
DEFAULT_PARAMETER_FILE = DATA_DIR / "sandia_arm.toml"
DESIGN_FILE = DATA_DIR / "sandia_arm_design.toml"

ELEMENT_NAMES = (
    "hub1", "bracket1", "link1_seg1", "link1_seg2", "link1_seg3",
    "bracket2_stator", "rotor2", "bracket3", "link2_seg1", "link2_seg2", "link2_seg3",
)
#: 0-based index of the element whose distal end is the tip of link 1 / link 2.
LINK1_TIP_ELEMENT = 4
LINK2_TIP_ELEMENT = 10
#: 0-based indices of the elements joined by the joint-2 motor (no spring there).
JOINT2_PAIR = (5, 6)
#: 0-based indices of the link segments (strain gauges) and their proximal neighbours.
STRAIN_GAUGE_ELEMENTS = (2, 3, 4, 8, 9, 10)
#: The springs inside the flexible links (0-based element pairs): the six the strain gauges read. The other springs
#: are the brackets' flexures. ``link_stiffness_scale`` scales these (a model error of the links, not the brackets).
LINK_SPRING_PAIRS = tuple((e - 1, e) for e in STRAIN_GAUGE_ELEMENTS)
#: The range of ``link_stiffness_scale``.
LINK_STIFFNESS_SCALE_RANGE = (0.5, 2.0)


class ParameterError(ValueError):
    """A parameter is missing or outside its allowed range."""


@dataclass(frozen=True)
class ArmParameters:
    """Parameters of the planar 11-element chain.

    All arrays are indexed by element (0-based). Lengths in m, masses in kg,
    inertias in kg·m², stiffness in N·m/rad, torques in N·m.

    Attributes
    ----------
    length : ndarray, shape (11,)
        Hinge-to-hinge length l_i.
    mass : ndarray, shape (11,)
        Element mass m_i.
    com : ndarray, shape (11,)
        Distance c_i from the proximal hinge to the centre of mass.
    inertia : ndarray, shape (11,)
        Centroidal moment of inertia J_i.
    spring_pairs : ndarray of int, shape (n_springs, 2)
        0-based element pairs joined by a torsional spring.
    spring_stiffness : ndarray, shape (n_springs,)
        Spring stiffness k.
    point_mass_element : ndarray of int, shape (n_points,)
        Element at whose distal end each point mass sits.
    point_mass : ndarray, shape (n_points,)
        Point masses (accelerometers), kg.
    payload_mass : float
        Extra point mass at the tip of link 2, kg (the paper's model error).
    link_stiffness_scale : float
        Factor on the stiffness of the flexible links' springs (:data:`LINK_SPRING_PAIRS`), 1 for the design model:
        a plant whose links are stiffer or softer than the model it was planned and designed on.
    peak_torque : ndarray, shape (2,)
        Motor peak torques.
    torque_limit_fraction : float
        Fraction of the peak torque the optimiser may use.
    line_start, line_end : ndarray, shape (2,)
        End points of the straight tip line, m.
    source : str
        File the parameters came from ('' when built in memory).
    sha256 : str
        SHA-256 of that file's bytes ('' when built in memory).
    """

    length: np.ndarray
    mass: np.ndarray
    com: np.ndarray
    inertia: np.ndarray
    spring_pairs: np.ndarray
    spring_stiffness: np.ndarray
    point_mass_element: np.ndarray
    point_mass: np.ndarray
    payload_mass: float = 0.0
    link_stiffness_scale: float = 1.0
    peak_torque: np.ndarray = field(default_factory=lambda: np.array([7.0, 2.25]))
    torque_limit_fraction: float = 0.8
    line_start: np.ndarray = field(default_factory=lambda: np.array([0.6, -0.75]))
    line_end: np.ndarray = field(default_factory=lambda: np.array([0.6, 0.75]))
    source: str = ""
    sha256: str = ""

    def __post_init__(self):
        for name in ("length", "mass", "com", "inertia"):
            arr = np.asarray(getattr(self, name), dtype=float)
            if arr.shape != (N_ELEMENTS,):
                raise ParameterError(f"{name}: expected {N_ELEMENTS} values, got shape {arr.shape}")
            if not np.all(np.isfinite(arr)) or np.any(arr < 0):
                raise ParameterError(f"{name}: every value must be finite and >= 0, got {arr}")
            object.__setattr__(self, name, arr)
        _check_scalar("payload_mass", self.payload_mass, 0.0, 10.0)
        _check_scalar("link_stiffness_scale", self.link_stiffness_scale, *LINK_STIFFNESS_SCALE_RANGE)
        if np.any(self.com > self.length + 1e-12):
            raise ParameterError("com: centre of mass must lie between the hinges (0 <= c_i <= l_i)")
        pairs = np.asarray(self.spring_pairs, dtype=np.int64).reshape(-1, 2)
        k = np.asarray(self.spring_stiffness, dtype=float)
        if k.shape != (len(pairs),) or np.any(~np.isfinite(k)) or np.any(k <= 0):
            raise ParameterError("spring_stiffness: one finite value > 0 per spring pair")
        object.__setattr__(self, "spring_pairs", pairs)
        object.__setattr__(self, "spring_stiffness", k)
        pe = np.asarray(self.point_mass_element, dtype=np.int64)
        pm = np.asarray(self.point_mass, dtype=float)
        if pe.shape != pm.shape or np.any(pm < 0) or np.any((pe < 0) | (pe >= N_ELEMENTS)):
            raise ParameterError("point masses: element index in 0..10 and mass >= 0 for each")
        object.__setattr__(self, "point_mass_element", pe)
        object.__setattr__(self, "point_mass", pm)
        for name in ("peak_torque", "line_start", "line_end"):
            object.__setattr__(self, name, np.asarray(getattr(self, name), dtype=float))

    # -- derived constants -------------------------------------------------
    def carried_mass(self) -> np.ndarray:
        """mu_j: mass carried distal to element j's distal hinge, kg, shape (11,)."""
        mu = np.zeros(N_ELEMENTS)
        for j in range(N_ELEMENTS):
            mu[j] = self.mass[j + 1:].sum()
        for e, m in zip(self.point_mass_element, self.point_mass):
            mu[: e + 1] += m
        mu[: LINK2_TIP_ELEMENT + 1] += self.payload_mass
        return mu

    def mass_coefficients(self) -> np.ndarray:
        """Constant coefficients M_jk of the mass matrix (kg·m²), shape (11, 11).

        M_jj = J_j + m_j c_j² + l_j² μ_j and M_jk = l_j (m_k c_k + l_k μ_k)
        for j < k, symmetric. The configuration-dependent mass matrix is
        M_jk cos(θ_j − θ_k).
        """
        mu = self.carried_mass()
        l, m, c = self.length, self.mass, self.com
        first_moment = m * c + l * mu  # m_k c_k + l_k mu_k
        coeff = np.outer(l, first_moment)
        upper = np.triu(coeff, 1)
        out = upper + upper.T
        out[np.diag_indices(N_ELEMENTS)] = self.inertia + m * c**2 + l**2 * mu
        return out

    def stiffness_matrix(self) -> np.ndarray:
        """Laplacian stiffness matrix K (N·m/rad), shape (11, 11); off-diagonal −k.

        K = K_brackets + ``link_stiffness_scale`` · K_links (:meth:`stiffness_parts`; the native plant forms the same
        sum, so that both give the same bits).
        """
        brackets, links = self.stiffness_parts()
        return brackets + self.link_stiffness_scale * links

    def stiffness_parts(self) -> tuple[np.ndarray, np.ndarray]:
        """(K of the brackets' springs, K of the links' springs at scale 1), each (11, 11)."""
        links = {tuple(p) for p in LINK_SPRING_PAIRS}
        parts = np.zeros((2, N_ELEMENTS, N_ELEMENTS))
        for (i, j), k in zip(self.spring_pairs, self.spring_stiffness):
            K = parts[int((int(i), int(j)) in links)]
            K[i, j] -= k
            K[j, i] -= k
            K[i, i] += k
            K[j, j] += k
        return parts[0], parts[1]

    @property
    def torque_limit(self) -> np.ndarray:
        """Torque bound used by the optimiser, N·m, shape (2,)."""
        return self.torque_limit_fraction * self.peak_torque

    def with_payload(self, payload_mass: float) -> ArmParameters:
        """A copy with another tip payload (kg, 0 to 10)."""
        _check_scalar("payload_mass", payload_mass, 0.0, 10.0)
        return dataclasses.replace(self, payload_mass=float(payload_mass))

    def with_link_stiffness(self, scale: float) -> ArmParameters:
        """A copy whose flexible links' springs are `scale` times as stiff (:data:`LINK_STIFFNESS_SCALE_RANGE`)."""
        _check_scalar("link_stiffness_scale", scale, *LINK_STIFFNESS_SCALE_RANGE)
        return dataclasses.replace(self, link_stiffness_scale=float(scale))

    def reach(self) -> float:
        """Fully outstretched reach from the shoulder axis to the tip, m."""
        return float(self.length.sum())


def _check_scalar(name: str, value, lo: float, hi: float) -> None:
    if not isinstance(value, (int, float, np.floating, np.integer)) or not math.isfinite(value):
        raise ParameterError(f"{name}: must be a finite number in [{lo}, {hi}], got {value!r}")
    if not lo <= value <= hi:
        raise ParameterError(f"{name}: {value} is outside the allowed range [{lo}, {hi}]")


# -- loading -----------------------------------------------------------------
def _value(entry, where: str) -> float:
    if isinstance(entry, dict):
        if "value" not in entry:
            raise ParameterError(f"{where}: missing 'value'")
        entry = entry["value"]
    if isinstance(entry, list):
        return np.asarray(entry, dtype=float)
    if not isinstance(entry, (int, float)):
        raise ParameterError(f"{where}: expected a number, got {entry!r}")
    return float(entry)


def load_parameters(path: str | os.PathLike | None = None, payload_mass: float | None = None) -> ArmParameters:
    """Load a complete parameter file (default: the committed Sandia arm).

    Parameters
    ----------
    path : path-like, optional
        TOML file as written by :func:`write_parameter_file`.
    payload_mass : float, optional
        Override the file's tip payload, kg.
    """
    path = Path(path) if path is not None else DEFAULT_PARAMETER_FILE
    raw = path.read_bytes()
    try:
        doc = tomllib.loads(raw.decode())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError, RecursionError) as exc:
        raise ParameterError(f"{path}: not valid TOML: {exc}") from exc
    try:
        return _parameters_from(doc, path, raw, payload_mass)
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        if isinstance(exc, ParameterError):
            raise
        raise ParameterError(f"{path}: {type(exc).__name__}: {exc} (a table or key is missing or of the wrong "
                             f"type)") from exc


def _parameters_from(doc: dict, path: Path, raw: bytes, payload_mass: float | None) -> ArmParameters:
    elements = doc.get("element", [])
    if len(elements) != N_ELEMENTS:
        raise ParameterError(f"{path}: expected {N_ELEMENTS} [[element]] tables, found {len(elements)}")
    cols = {k: np.zeros(N_ELEMENTS) for k in ("length_m", "mass_kg", "com_m", "inertia_kgm2")}
    for i, el in enumerate(elements):
        for key in cols:
            if key not in el:
                raise ParameterError(f"{path}: element {i + 1}: missing '{key}'")
            cols[key][i] = _value(el[key], f"element {i + 1}.{key}")
    springs = doc.get("spring", [])
    pairs = [[int(s["between"][0]) - 1, int(s["between"][1]) - 1] for s in springs]
    stiff = [_value(s["stiffness_Nm_per_rad"], f"spring {s['between']}") for s in springs]
    points = doc.get("point_mass", [])
    motors = doc.get("motors", {})
    line = doc.get("line", {})
    payload = doc.get("payload", {})
    params = ArmParameters(
        length=cols["length_m"], mass=cols["mass_kg"], com=cols["com_m"], inertia=cols["inertia_kgm2"],
        spring_pairs=np.array(pairs, dtype=np.int64).reshape(-1, 2),
        spring_stiffness=np.array(stiff),
        point_mass_element=np.array([int(p["at_distal_end_of_element"]) - 1 for p in points], dtype=np.int64),
        point_mass=np.array([_value(p["mass_kg"], f"point mass {p.get('name')}") for p in points]),
        payload_mass=_value(payload.get("mass_kg", 0.0), "payload.mass_kg"),
        peak_torque=_value(motors.get("peak_torque_Nm", [7.0, 2.25]), "motors.peak_torque_Nm"),
        torque_limit_fraction=_value(motors.get("torque_limit_fraction", 0.8), "motors.torque_limit_fraction"),
        line_start=_value(line.get("start_m", [0.6, -0.75]), "line.start_m"),
        line_end=_value(line.get("end_m", [0.6, 0.75]), "line.end_m"),
        source=str(path), sha256=hashlib.sha256(raw).hexdigest(),
    )
    if payload_mass is not None:
        params = params.with_payload(payload_mass)
    return params


def load_design(path: str | os.PathLike | None = None) -> dict:
    """The design file as a dict (paper facts, choices, calibration set-up)."""
    return tomllib.loads(Path(path or DESIGN_FILE).read_text())


# -- building from the design ------------------------------------------------
def build_from_design(design: dict, unknowns: dict[str, float]) -> tuple[ArmParameters, list[dict]]:
    """Assemble the 11-element parameters from design inputs and fitted unknowns.

    Returns the parameters and, per element/spring/point mass, a record of each
    value with its source and formula (used to write the parameter file).
    """
    p, ch = design["paper"], design["chosen"]
    rho = ch["aluminium_density_kgm3"]
    nseg = int(p["segments_per_link"])
    lb, mb = ch["bracket_length_m"], ch["bracket_mass_kg"]
    records = []

    def link_segment(k: int) -> dict:
        L, w, h = p[f"link{k}_flexible_length_m"], p[f"link{k}_width_m"], p[f"link{k}_thickness_m"]
        a = L / nseg
        m = rho * L * w * h / nseg
        return {
            "length_m": (a, "derived", f"link{k} flexible length / {nseg} (paper)"),
            "mass_kg": (m, "derived", f"density x {L} x {w} x {h} / {nseg}"),
            "com_m": (a / 2, "derived", "uniform segment: half its length"),
            "inertia_kgm2": (m * (a**2 + h**2) / 12, "derived", "m (a^2 + h^2) / 12, bending in the plane"),
        }

    bracket = {
        "length_m": (lb, "chosen", "bracket length"),
        "mass_kg": (mb, "chosen", "bracket mass"),
        "com_m": (lb / 2, "derived", "uniform block: half its length"),
        "inertia_kgm2": (mb * lb**2 / 12, "derived", "m l^2 / 12"),
    }
    ms = unknowns["stator_mass_kg"]
    rs = ch["stator_radius_m"]
    stator = {
        # Bracket 2 plus the stator, whose centre of mass is on the joint-2 axis
        # (the distal hinge of element 6).
        "length_m": (lb, "chosen", "bracket length"),
        "mass_kg": (mb + ms, "calibrated", f"bracket {mb} kg + fitted stator {ms:.4f} kg"),
        "com_m": ((mb * lb / 2 + ms * lb) / (mb + ms), "derived", "bracket at l/2, stator on the joint-2 axis"),
        "inertia_kgm2": (
            mb * lb**2 / 12 + mb * ((mb * lb / 2 + ms * lb) / (mb + ms) - lb / 2) ** 2
            + 0.5 * ms * rs**2 + ms * (lb - (mb * lb / 2 + ms * lb) / (mb + ms)) ** 2,
            "derived", f"bracket + stator as a cylinder of radius {rs} m, about the combined centre of mass",
        ),
    }
    elements = [
        {
            "length_m": (ch["hub_radius_m"], "chosen", "axis to bracket-1 mount"),
            "mass_kg": (ch["hub_mass_kg"], "chosen", "centre of mass on the fixed axis: no effect on dynamics"),
            "com_m": (0.0, "chosen", "on the axis"),
            "inertia_kgm2": (unknowns["hub_inertia_kgm2"], "calibrated", "hub + motor-1 rotor"),
        },
        bracket,
        *[link_segment(1) for _ in range(nseg)],
        stator,
        {
            "length_m": (ch["rotor2_radius_m"], "chosen", "axis to bracket-3 mount"),
            "mass_kg": (ch["rotor2_mass_kg"], "chosen", "motor-2 rotor, on the joint-2 axis"),
            "com_m": (0.0, "chosen", "on the axis"),
            "inertia_kgm2": (unknowns["rotor2_inertia_kgm2"], "calibrated", "hub + motor-2 rotor"),
        },
        bracket,
        *[link_segment(2) for _ in range(nseg)],
    ]
    for i, el in enumerate(elements):
        records.append({"kind": "element", "index": i + 1, "name": ELEMENT_NAMES[i], **el})

    # Springs. The strain gauge of each link segment reads the spring at the
    # segment's proximal hinge (eqs. 23-31), so each link has three springs,
    # Hencky bar chain: 2EI/a at the clamped root (half a segment of beam),
    # EI/a between segments. Each bracket's flexure (EI_b over its length) is
    # the spring at its hinge to the neighbouring link, so θ_2 ≈ θ_1,
    # θ_6 ≈ θ_5 and θ_8 ≈ θ_7 to micro-radians, as eqs. 22, 26, 28 assume.
    EIb = p["bracket_EI_Nm2"]
    a1 = p["link1_flexible_length_m"] / nseg
    a2 = p["link2_flexible_length_m"] / nseg
    EI1, EI2 = p["link1_EI_Nm2"], p["link2_EI_Nm2"]
    springs = [
        ((1, 2), EIb / lb, "EI_bracket / l_bracket (bracket-1 flexure)"),
        ((2, 3), 2 * EI1 / a1, "2 EI1 / a1 (link-1 root: half a segment clamped in bracket 1)"),
        ((3, 4), EI1 / a1, "EI1 / a1"),
        ((4, 5), EI1 / a1, "EI1 / a1"),
        ((5, 6), EIb / lb, "EI_bracket / l_bracket (bracket-2 flexure at the link-1 tip)"),
        ((7, 8), EIb / lb, "EI_bracket / l_bracket (bracket-3 flexure)"),
        ((8, 9), 2 * EI2 / a2, "2 EI2 / a2 (link-2 root: half a segment clamped in bracket 3)"),
        ((9, 10), EI2 / a2, "EI2 / a2"),
        ((10, 11), EI2 / a2, "EI2 / a2"),
    ]
    for pair, k, formula in springs:
        records.append({"kind": "spring", "between": pair, "stiffness": (k, "derived", formula)})
    points = [
        ("accelerometer1", LINK1_TIP_ELEMENT, ch["accelerometer1_mass_kg"], "chosen"),
        ("accelerometer2", LINK2_TIP_ELEMENT, unknowns["accelerometer2_mass_kg"], "calibrated"),
    ]
    for name, e, m, src in points:
        records.append({"kind": "point_mass", "name": name, "element": e + 1, "mass": (m, src, "at the link tip")})

    def col(key):
        return np.array([el[key][0] for el in elements])

    params = ArmParameters(
        length=col("length_m"), mass=col("mass_kg"), com=col("com_m"), inertia=col("inertia_kgm2"),
        spring_pairs=np.array([[a - 1, b - 1] for (a, b), _, _ in springs]),
        spring_stiffness=np.array([k for _, k, _ in springs]),
        point_mass_element=np.array([e for _, e, _, _ in points]),
        point_mass=np.array([m for _, _, m, _ in points]),
        peak_torque=np.array(p["peak_torque_Nm"], dtype=float),
        torque_limit_fraction=float(p["torque_limit_fraction"]),
        line_start=np.array(design["line"]["start_m"], dtype=float),
        line_end=np.array(design["line"]["end_m"], dtype=float),
    )
    return params, records


def _fmt(x: float) -> str:
    return repr(float(x))


def write_parameter_file(path: str | os.PathLike, params: ArmParameters, records: list[dict],
                         header: str) -> None:
    """Write a complete parameter file atomically (temporary file, then rename)."""
    lines = [f"# {line}" if line else "#" for line in header.splitlines()]
    lines += ["", "[motors]",
              f"peak_torque_Nm = {{ value = [{_fmt(params.peak_torque[0])}, {_fmt(params.peak_torque[1])}], "
              "source = \"paper\" }",
              f"torque_limit_fraction = {{ value = {_fmt(params.torque_limit_fraction)}, source = \"paper\" }}",
              "", "[line]",
              "# Straight tip line of the slew: chosen (not in the paper), see the design file.",
              f"start_m = {{ value = [{_fmt(params.line_start[0])}, {_fmt(params.line_start[1])}], "
              "source = \"chosen\" }",
              f"end_m = {{ value = [{_fmt(params.line_end[0])}, {_fmt(params.line_end[1])}], source = \"chosen\" }}",
              "", "[payload]",
              "# Extra tip mass (the paper's 0.275 kg model error). Scenarios override it.",
              f"mass_kg = {{ value = {_fmt(params.payload_mass)}, source = \"scenario\" }}"]
    for rec in records:
        lines.append("")
        if rec["kind"] == "element":
            lines += ["[[element]]", f"index = {rec['index']}", f"name = \"{rec['name']}\""]
            for key in ("length_m", "mass_kg", "com_m", "inertia_kgm2"):
                v, src, note = rec[key]
                lines.append(f"{key} = {{ value = {_fmt(v)}, source = \"{src}\", note = \"{note}\" }}")
        elif rec["kind"] == "spring":
            v, src, note = rec["stiffness"]
            lines += ["[[spring]]", f"between = [{rec['between'][0]}, {rec['between'][1]}]",
                      f"stiffness_Nm_per_rad = {{ value = {_fmt(v)}, source = \"{src}\", formula = \"{note}\" }}"]
        else:
            v, src, note = rec["mass"]
            lines += ["[[point_mass]]", f"name = \"{rec['name']}\"", f"at_distal_end_of_element = {rec['element']}",
                      f"mass_kg = {{ value = {_fmt(v)}, source = \"{src}\", note = \"{note}\" }}"]
    text = "\n".join(lines) + "\n"
    tomllib.loads(text)  # never write a file we could not read back
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def calibrated_unknowns(params, design: dict) -> dict[str, float]:
    """The calibrated unknowns read back from a parameter set (inverse of ``build_from_design``)."""
    mb = design["chosen"]["bracket_mass_kg"]
    return {
        "hub_inertia_kgm2": float(params.inertia[0]),
        "stator_mass_kg": float(params.mass[5] - mb),
        "rotor2_inertia_kgm2": float(params.inertia[6]),
        "accelerometer2_mass_kg": float(params.point_mass[-1]),
    }
