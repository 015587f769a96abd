"""Gain-set names: the LQR weights by name, and the aliases the controllers accept.

One place for the names (``flexarm.lqr_design`` designs them, ``flexarm.gain_schedule``
files them, the controller FMUs' ``gain_set`` parameter and the scenario files use them):

* ``gamma1``, ``gamma0.1``, ``gamma0``: Q = diag(10·I11, γ·I11) (eq. 20 of the paper);
* ``eq32``: the experimental Q = diag(10·I11, 80, 0.8·I5, 4, 0.8·I4) (eq. 32);
* ``dlqr-<name>``: the discrete-time design of the same weights on the 1 ms
  zero-order-hold model (``dlqr`` alone means ``dlqr-gamma0.1``).

All with R = 10·I2 (eq. 19). The controller FMUs' ``gain_set`` Enumeration lists
:data:`WEIGHT_NAMES` as items 1..4 (in that order); :func:`resolve_gain_set`
also accepts the older spellings ``gamma_0.1``, ``experimental`` (= ``eq32``) and
``dlqr_<name>``.
"""

from __future__ import annotations

import numpy as np

from .model import N

#: Base names of the state weights, in the order of the FMUs' ``GainSet`` Enumeration (items 1..4).
WEIGHT_NAMES = ("gamma1", "gamma0.1", "gamma0", "eq32")
#: Prefix of the discrete-time designs.
DISCRETE_PREFIX = "dlqr-"
#: Every gain-set name the design CLI writes.
GAIN_SET_NAMES = WEIGHT_NAMES + tuple(f"{DISCRETE_PREFIX}{w}" for w in WEIGHT_NAMES)
#: Short names: alias -> gain-set name.
NAME_ALIASES = {"dlqr": "dlqr-gamma0.1"}
#: Weight aliases the controllers accept besides :data:`WEIGHT_NAMES`.
WEIGHT_ALIASES = {"experimental": "eq32"}
#: The controllers' default gain set.
DEFAULT_GAIN_SET = "gamma0.1"


class GainError(ValueError):
    """A gain-set name, schedule or gain file is invalid."""


def state_weight(name: str) -> np.ndarray:
    """State weight Q (22×22) of a named design.

    Parameters
    ----------
    name : str
        ``gamma1``, ``gamma0.1``, ``gamma0`` (eq. 20, Q = diag(10·I11, γ·I11)),
        ``eq32`` (eq. 32), or any ``gamma<float>`` with 0 ≤ γ ≤ 100;
        a ``dlqr-`` prefix is ignored.

    Returns
    -------
    ndarray, shape (22, 22)
    """
    base = name.removeprefix(DISCRETE_PREFIX)
    if base == "eq32":
        vel = np.full(N, 0.8)
        vel[0] = 80.0  # θ̇1: most of the observed overshoot was in link 1
        vel[6] = 4.0  # θ̇7
        return np.diag(np.r_[np.full(N, 10.0), vel])
    if base.startswith("gamma"):
        try:
            gamma = float(base[5:])
        except ValueError:
            gamma = float("nan")
        if np.isfinite(gamma) and 0.0 <= gamma <= 100.0:
            return np.diag(np.r_[np.full(N, 10.0), np.full(N, gamma)])
    raise GainError(f"gain set name: {name!r} is not one of {GAIN_SET_NAMES + tuple(NAME_ALIASES)} "
                    "(or gamma<γ> with 0 <= γ <= 100)")


def canonical_name(name: str) -> str:
    """Resolve the alias ``dlqr`` (= ``dlqr-gamma0.1``) and check the name."""
    name = NAME_ALIASES.get(name, name)
    state_weight(name)
    return name


def is_discrete(name: str) -> bool:
    """True for discrete-time (``dlqr-``) designs."""
    return canonical_name(name).startswith(DISCRETE_PREFIX)


def gain_set_from_item(value: int, discrete: bool = False) -> str:
    """The gain-set name of an item of the FMUs' ``GainSet`` Enumeration (1..4: :data:`WEIGHT_NAMES` in order).

    Raises
    ------
    GainError
        Naming ``gain_set`` and the allowed values.
    """
    if isinstance(value, bool) or value not in range(1, len(WEIGHT_NAMES) + 1):
        raise GainError(f"gain_set: {value!r} is not one of "
                        + ", ".join(f"{i} ({n})" for i, n in enumerate(WEIGHT_NAMES, 1)))
    name = WEIGHT_NAMES[int(value) - 1]
    return f"{DISCRETE_PREFIX}{name}" if discrete else name


def resolve_gain_set(value: str, discrete: bool = False) -> str:
    """The gain-set name of a controller's ``gain_set`` value (names and aliases).

    Parameters
    ----------
    value : str
        ``gamma1``, ``gamma0.1``, ``gamma0``, ``eq32``, ``dlqr-<set>``,
        ``dlqr`` (= ``dlqr-gamma0.1``); also ``gamma_1``-style names,
        ``experimental`` (= ``eq32``) and ``dlqr_<set>``.
    discrete : bool
        Return the discrete (``dlqr-``) design of the same weights.

    Raises
    ------
    GainError
        Naming ``gain_set`` and the allowed names.
    """
    name = value.strip()
    if name in NAME_ALIASES:
        name = NAME_ALIASES[name]
    is_dlqr = name.startswith((DISCRETE_PREFIX, "dlqr_"))
    base = name[len(DISCRETE_PREFIX):] if is_dlqr else name
    base = WEIGHT_ALIASES.get(base, base)
    if base.startswith("gamma_"):
        base = "gamma" + base[6:]
    name = f"{DISCRETE_PREFIX}{base}" if discrete or is_dlqr else base
    try:
        return canonical_name(name)
    except GainError as exc:
        raise GainError(f"gain_set: {value!r} is not a gain set ({exc})") from None
