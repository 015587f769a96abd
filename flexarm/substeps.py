"""How many substeps a communication step takes (no kernels: cheap to import, e.g. for a run's loop check).

See :mod:`flexarm.integrator`, which re-exports both names.
"""

from __future__ import annotations

import math

#: RK4 steps per millisecond of the reference scheme, per unit of ``substeps`` (default 2: 400/ms, 2.5 µs).
REFERENCE_STEPS_PER_SUBSTEP = 200


def substep_count(dt: float, substeps: int, integrator: str = "rodas4") -> int:
    """Number of equal substeps for a step of dt seconds at `substeps` per millisecond (at least one).

    A step within 1e-6 of a whole number of substeps counts as that number (no extra sliver substep from
    round-off, e.g. dt = 0.004000000000000001). The reference scheme takes
    :data:`REFERENCE_STEPS_PER_SUBSTEP` RK4 steps per substep.
    """
    per_ms = int(substeps) * (REFERENCE_STEPS_PER_SUBSTEP if integrator == "reference" else 1)
    return max(1, math.ceil(dt / 1e-3 * per_ms - 1e-6))
