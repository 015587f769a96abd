"""The private APIs of other packages this project uses, each wrapped once (versions pinned in pyproject.toml).

* fmpy 0.3.32: ``FMU2Slave._functions``, the raw ctypes functions of an FMU
  (the master calls ``fmi2GetReal``/``fmi2SetReal``/``fmi2DoStep`` on
  preallocated buffers, without fmpy's per-call allocation and logging);
* libcosimpy 0.0.6: ``libcosimpy._internal`` (``libcosimc``, ``wrap_function``,
  ``get_last_error_message``), for the last error message and for reading an
  observer's samples from step 0 (libcosimpy's reader drops sample 0).

If a newer version moves them, this module is the one place to change.
"""

from __future__ import annotations

import ctypes

#: The versions these wrappers were written against (pyproject.toml pins them).
FMPY_VERSION = "0.3.32"
LIBCOSIMPY_VERSION = "0.0.6"


def fmu2_raw_functions(slave) -> tuple:
    """(fmi2GetReal, fmi2SetReal, fmi2DoStep) of an instantiated ``fmpy.fmi2.FMU2Slave``, as ctypes functions."""
    try:
        functions = slave._functions
        return functions["fmi2GetReal"], functions["fmi2SetReal"], functions["fmi2DoStep"]
    except (AttributeError, KeyError) as exc:
        import fmpy

        raise RuntimeError(f"fmpy {fmpy.__version__}: FMU2Slave._functions is not as in fmpy {FMPY_VERSION} "
                           f"({exc}); install fmpy=={FMPY_VERSION}") from exc


def libcosim_last_error() -> str:
    """libcosim's last error message, or '(no message)'."""
    from libcosimpy._internal import get_last_error_message

    return get_last_error_message() or "(no message)"


def libcosim_real_samples_reader():
    """``cosim_observer_slave_get_real_samples`` of libcosimc as a ctypes function (reads from any step, 0 too)."""
    from libcosimpy._internal import libcosimc, wrap_function

    return wrap_function(
        lib=libcosimc(), funcname="cosim_observer_slave_get_real_samples",
        argtypes=[ctypes.c_void_p, ctypes.c_int, ctypes.c_uint32, ctypes.c_int64, ctypes.c_size_t,
                  ctypes.POINTER(ctypes.c_double), ctypes.POINTER(ctypes.c_int64), ctypes.POINTER(ctypes.c_int64)],
        restype=ctypes.c_int64)
