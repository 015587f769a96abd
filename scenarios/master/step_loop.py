"""The stepping loop in C (``step_loop.c``) for FMUs in the master's process: the same FMI calls, less overhead.

:meth:`scenarios.master.cosim.Master.run` steps through its plan of port reads and link writes
(:class:`scenarios.master.units.Port`, :class:`~scenarios.master.units.Link`) at every communication point. In
Python that loop cost about 13 µs a step of ctypes calls and NumPy operations for three FMUs, more than the native
plant's own step (issue 34: three native FMUs at ≥ 50× real time). :class:`CompiledLoop` hands the same plan to
``flexarm_step_loop``, which makes the same calls in the same order on the same buffers, gathers the recorded rows
and checks them for divergence, and returns to Python between chunks of steps (progress, Ctrl-C) and at the first
problem, which the master then reports as before. The loop's results are the Python loop's bit for bit
(``tests/test_master_step_loop.py``).

The C file is compiled once per machine with the C compiler (``$CC``, ``cc``, ``gcc`` or ``clang``) into the user's
cache folder (:func:`flexarm.user_cache.user_cache_folder`), under the SHA-256 of the source, the compiler and the
platform. Without a compiler, with ``FLEXARM_MASTER_LOOP=python``, for FMUs isolated in their own processes, and for
the first communication point of an ``fmpy-ssp`` run (its zeros), and for FMU functions wrapped in Python, the
Python loop runs.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from flexarm.user_cache import c_compiler, user_cache_folder

SOURCE = Path(__file__).with_name("step_loop.c")
#: ``FLEXARM_MASTER_LOOP=python`` runs the Python loop (the reference the C loop is tested against).
LOOP_VARIABLE = "FLEXARM_MASTER_LOOP"
STEP_DONE, STEP_UNBOUNDED, STEP_FAILED = 0, 1, 2
FUNCTIONS = ("fmi2GetReal", "fmi2SetReal", "fmi2DoStep")

_i64, _p = ctypes.c_int64, ctypes.c_void_p


class _Op(ctypes.Structure):
    _fields_ = [("kind", _i64), ("unit", _i64), ("function", _p), ("component", _p), ("vrs", _p), ("n", _i64),
                ("buffer", _p), ("source", _p), ("index", _p)]


class _Unit(ctypes.Structure):
    _fields_ = [("do_step", _p), ("component", _p)]


class _Gather(ctypes.Structure):
    _fields_ = [("source", _p), ("cols", _p), ("pos", _p), ("n", _i64)]


_LIBRARY: list = []  # [the loaded function or None], once per process


def loop_function():
    """``flexarm_step_loop`` from the compiled library (compiled now if this machine has none yet), or None."""
    if os.environ.get(LOOP_VARIABLE, "c") == "python":
        return None
    if _LIBRARY:
        return _LIBRARY[0]
    _LIBRARY.append(None)
    compiler = c_compiler()
    if compiler is None:
        return None
    try:
        source = SOURCE.read_bytes()
    except OSError:  # a package installed without its C file: the Python loop
        return None
    flags = ["-O2", "-fPIC", "-shared"]
    key = hashlib.sha256(b"\0".join([source, compiler.encode(), " ".join(flags).encode(), sys.platform.encode(),
                                     platform.machine().encode()])).hexdigest()[:24]
    suffix = {"win32": ".dll", "darwin": ".dylib"}.get(sys.platform, ".so")
    library = user_cache_folder("master", key) / f"step_loop{suffix}"
    try:
        if not library.exists():
            library.parent.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryDirectory(dir=library.parent) as tmp:
                built = Path(tmp) / library.name
                done = subprocess.run([compiler, *flags, str(SOURCE), "-o", str(built), "-lm"], capture_output=True)
                if done.returncode != 0:
                    return None
                os.replace(built, library)
        fn = ctypes.CDLL(str(library)).flexarm_step_loop
    except OSError:  # an unwritable cache, a library that does not load: the Python loop
        return None
    fn.restype = _i64
    fn.argtypes = [_i64, _i64, _i64, _p, _p, _i64, _p, _i64, _p, _i64, _p, _p, _i64, ctypes.c_double, _p]
    _LIBRARY[0] = fn
    return fn


def calls_c(unit) -> bool:
    """Whether `unit`'s fmi2GetReal, fmi2SetReal and fmi2DoStep are C functions the loop can call: not for an FMU
    in its own process (Python proxies), nor for functions wrapped in Python (a test's failing fmi2DoStep)."""
    return not unit.isolated and all(isinstance(f, ctypes._CFuncPtr) for f in (unit.get_real, unit.set_real,
                                                                                unit.do_step))


def _address(buffer) -> int:
    return ctypes.addressof(buffer)


def _positions(index, n: int) -> np.ndarray:
    """A slice or an index array as an int64 array of n positions."""
    if isinstance(index, slice):
        return np.arange(index.start, index.stop, dtype=np.int64)
    out = np.ascontiguousarray(index, dtype=np.int64)
    assert out.size == n
    return out


class CompiledLoop:
    """The plan of one run, laid out for ``flexarm_step_loop``.

    Parameters
    ----------
    fn : ctypes function
        :func:`loop_function`.
    ops : list
        The plan's operations, each a bound ``Port.read`` or ``Link.write``.
    units : list of Unit
        The FMUs in stepping order.
    gathers : list of (Port, cols, pos)
        The recorded values of each port and where they go in a row.
    data : ndarray, shape (n + 1, n_cols)
        The recorded rows (C order, float64), written in place.
    time, steps : ndarray
        Communication points and step sizes.
    limit : float
        The divergence limit.
    """

    def __init__(self, fn, ops, units, gathers, data, time, steps, limit: float):
        from .units import Link, Port

        self.fn, self.units, self.data = fn, list(units), data
        self._keep = []  # arrays the C structures point into
        records = []
        index = {id(u): i for i, u in enumerate(self.units)}
        for op in ops:
            owner = op.__self__
            if isinstance(owner, Port) and op.__func__ is Port.read:
                unit = owner.unit
                records.append(_Op(0, index[id(unit)], ctypes.cast(unit.get_real, _p).value, unit.slave.component,
                                   _address(owner.vrs), owner.n, _address(owner.buffer), None, None))
            elif isinstance(owner, Link) and op.__func__ is Link.write:
                unit, positions = owner.dst, _positions(owner.index, owner.n)
                self._keep.append(positions)
                records.append(_Op(1, index[id(unit)], ctypes.cast(unit.set_real, _p).value, unit.slave.component,
                                   _address(owner.dst_vrs), owner.n, _address(owner.buffer),
                                   _address(owner.port.buffer), positions.ctypes.data))
            else:
                raise TypeError(f"not a port read or link write: {op!r}")
        self.ops = (_Op * len(records))(*records)
        self.steppers = (_Unit * len(self.units))(*[_Unit(ctypes.cast(u.do_step, _p).value, u.slave.component)
                                                   for u in self.units])
        gather_records = []
        for port, cols, pos in gathers:
            n = len(range(*cols.indices(data.shape[1]))) if isinstance(cols, slice) else len(cols)
            c, p = _positions(cols, n), _positions(pos, n)
            self._keep += [c, p]
            gather_records.append(_Gather(_address(port.buffer), c.ctypes.data, p.ctypes.data, n))
        self.gathers = (_Gather * max(1, len(gather_records)))(*gather_records)
        self.n_gathers = len(gather_records)
        self.time = np.ascontiguousarray(time, dtype=np.float64)
        self.steps = np.ascontiguousarray(steps, dtype=np.float64)
        assert data.flags.c_contiguous and data.dtype == np.float64
        self.limit = float(limit)
        self.out = np.zeros(6, dtype=np.int64)

    def run(self, k0: int, k1: int, n_last: int) -> int:
        """Communication points k0 .. k1 - 1 (see ``step_loop.c``); the status, with :attr:`out` its details."""
        return self.fn(k0, k1, n_last, self.time.ctypes.data, self.steps.ctypes.data, len(self.ops),
                       ctypes.addressof(self.ops), len(self.units), ctypes.addressof(self.steppers), self.n_gathers,
                       ctypes.addressof(self.gathers), self.data.ctypes.data, self.data.shape[1], self.limit,
                       self.out.ctypes.data)

    def failure(self):
        """The :class:`FMUError` of a STEP_FAILED return, made by the failing FMU as the Python loop makes it."""
        fn, which, status = (int(v) for v in self.out[2:5])
        return self.units[which].error(FUNCTIONS[fn], status)
