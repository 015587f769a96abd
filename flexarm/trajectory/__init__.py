"""Minimum-time straight-line slew of the flexible arm (paper section 2, eq. 3).

Run ``python -m flexarm.trajectory`` to regenerate the committed
``flexarm/data/trajectory.npz`` (1 ms samples) and ``trajectory.json``
(metadata); ``--help`` lists the options. docs/trajectory.md describes the
problem, the method and the file.

Modules, by concern:

``io``        the file and its data type (:class:`TrajectoryResult`, :func:`load_trajectory`,
              :func:`save_trajectory`); imports no CasADi.
``geometry``  inverse kinematics and the distance from the line.
``problem``   reduced models, Radau collocation and the NLP (CasADi/IPOPT).
``solve``     the staged solve (:func:`solve_minimum_time`), FATROP's re-plan (:func:`replan_minimum_time`),
              1 ms sampling, sensitivity.
``stage_form`` the NLP in stage form for FATROP (the re-plan).
``compiled``  a solver on interval functions compiled to C, made once per machine and cached.
``report``    replay in the plant, constraint checks, plot, command line.

Reading a trajectory (``from flexarm.trajectory import load_trajectory``)
does not import CasADi: the solver's names are loaded on first use.
"""

from __future__ import annotations

import importlib

from .geometry import inverse_kinematics, line_distance
from .io import (
    DEFAULT_PLOT_FILE,
    DEFAULT_TRAJECTORY_FILE,
    PAPER_TF,
    REGENERATE_COMMAND,
    SAMPLE_TIME,
    StaleTrajectoryError,
    TrajectoryError,
    TrajectoryResult,
    check_parameter_chain,
    load_trajectory,
    save_trajectory,
)

#: Names loaded from a submodule on first access (they import CasADi or the plant).
_LAZY = {
    "solve_minimum_time": "solve", "replan_minimum_time": "solve",
    "solve_free_time": "solve", "sample_solution": "solve", "sensitivity": "solve",
    "solve_collocation": "problem", "CollocationSolution": "problem", "ReducedModel": "problem",
    "RIGID_GROUPS": "problem", "FLEX_GROUPS": "problem", "DEFAULT_REGULARISATION": "problem",
    "LINE_TOLERANCE": "problem", "TORQUE_RATE_LIMIT": "problem",
    "verify_against_plant": "report", "check_constraints": "report", "plot_trajectory": "report",
    "main": "report",
}

__all__ = ["DEFAULT_PLOT_FILE", "DEFAULT_TRAJECTORY_FILE", "PAPER_TF", "REGENERATE_COMMAND", "SAMPLE_TIME",
           "StaleTrajectoryError", "TrajectoryError", "TrajectoryResult", "check_parameter_chain",
           "inverse_kinematics", "line_distance", "load_trajectory", "save_trajectory", *_LAZY]


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
