"""A CasADi solver whose per-interval functions are compiled to C, made once per machine and cached (issue 32).

The re-plan's FATROP solver (:mod:`flexarm.trajectory.stage_form`) is an MX graph of N calls of one small SX
function per interval. Interpreted by CasADi's virtual machine, evaluating that function's derivatives was about
two thirds of a re-plan's solve, and making the solver (CasADi's AD and sparsity analysis of the graph) took as
long again as a re-plan's first stage. Here:

* the interval functions, and the derivatives CasADi's AD asks of them (their Jacobian ``jac_<f>``, their reverse
  sweep ``adj1_<f>`` and that sweep's Jacobian ``jac_adj1_<f>``, the names an ``external`` looks up), are written
  as C by CasADi's code generator and compiled into one shared library (about 30 CPU-s of ``cc -O1``; ``-O0``
  halves the compile and makes every solve about 1.5x dearer);
* the solver is made on those compiled functions and saved with CasADi's serialisation; a later process loads it
  in under a second (the file is about 110 MB: the MX graph of the NLP's derivatives, not the C);
* both live in a cache folder named after the SHA-256 of what they are made from: the serialised interval
  functions (so the model, the grid and the constraints), the solver's options, CasADi's version, the platform
  and the compiler. A changed model or option makes a new entry; nothing is ever reused across a change.

Without a C compiler (``$CC``, else ``cc``, ``gcc`` or ``clang`` on the PATH) :func:`load_or_make` returns None and
the caller makes the interpreted solver, as before; ``FLEXARM_COMPILED_SOLVERS=0`` asks for that too.
Writes are atomic (a temporary name, then a rename), so concurrent processes that build the same entry do not read
each other's half-written files. An entry is about 110 MB, so the cache keeps the :data:`KEEP_ENTRIES` entries of
each solver used last (a load marks its entry used) and removes older ones when it makes a new one.
"""

from __future__ import annotations

import hashlib
import os
import platform
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path

import casadi as ca

from ..progress import heartbeat, say
from ..user_cache import c_compiler as find_c_compiler
from ..user_cache import user_cache_folder

#: C compiler options: -O1 compiles the re-plan's functions in about 30 CPU-s; -O2 is slower to compile for no
#: measured gain in a re-plan (benchmarks/bench_trajectory.py prints the re-plan's evaluation time).
CFLAGS = ("-O1", "-fPIC", "-shared")
#: The environment variable that turns compiled solvers off ("0") and the one that moves the cache.
DISABLE_VARIABLE, CACHE_VARIABLE = "FLEXARM_COMPILED_SOLVERS", "FLEXARM_SOLVER_CACHE"


#: Entries kept per solver name: this version's and one more (two checkouts of different versions do not remake
#: each other's); older ones, by last use, are removed when a new entry is made.
KEEP_ENTRIES = 2


def cache_folder() -> Path:
    """``$FLEXARM_SOLVER_CACHE``, else the user's cache folder (:func:`flexarm.user_cache.user_cache_folder`) +
    ``solvers``."""
    if os.environ.get(CACHE_VARIABLE):
        return Path(os.environ[CACHE_VARIABLE])
    return user_cache_folder("solvers")


def c_compiler() -> str | None:
    """The C compiler (:func:`flexarm.user_cache.c_compiler`), or None when compiled solvers are turned off."""
    if os.environ.get(DISABLE_VARIABLE, "1") == "0":
        return None
    return find_c_compiler()


def entry_key(name: str, functions: Sequence[ca.Function], solver_options: str, compiler: str) -> str:
    """The cache entry's name: SHA-256 (first 24 hex digits) of everything the library and the solver come from."""
    h = hashlib.sha256()
    for part in (name, ca.__version__, sys.platform, platform.machine(), compiler, " ".join(CFLAGS), solver_options,
                 *(f.serialize() for f in functions)):
        h.update(part.encode())
        h.update(b"\0")
    return h.hexdigest()[:24]


def _library_suffix() -> str:
    return {"win32": ".dll", "darwin": ".dylib"}.get(sys.platform, ".so")


def _compile(functions: Sequence[ca.Function], fixed_inputs: Sequence[str], library: Path, compiler: str,
             progress: Callable[[str], None]) -> None:
    """Write `functions` and the derivatives an ``external`` looks up as C, compile them into `library`."""
    cg = ca.CodeGenerator(f"{library.stem}.c", {"with_header": False})
    for f in functions:
        ins = [ca.SX.sym(f.name_in(i), f.sparsity_in(i)) for i in range(f.n_in())]
        # inputs the solver never differentiates (the NLP's parameters): no derivative code for them
        diff = [f.name_in(i) not in fixed_inputs for i in range(f.n_in())]
        g = ca.Function(f.name(), ins, f.call(ins), f.name_in(), f.name_out(), {"is_diff_in": diff})
        adjoint = g.reverse(1)
        for h in (g, g.jacobian(), adjoint, adjoint.jacobian()):
            cg.add(h)
    with tempfile.TemporaryDirectory(dir=library.parent) as tmp:
        source = Path(tmp) / f"{library.stem}.c"
        cg.generate(f"{tmp}{os.sep}")
        out = Path(tmp) / library.name
        command = [compiler, *CFLAGS, str(source), "-o", str(out), "-lm"]
        progress(f"compiling {source.stat().st_size / 1e6:.1f} MB of C once for this machine: {' '.join(command[:4])} "
                 "... (about 30 CPU-s)")
        with heartbeat(f"compiling {library.name}", emit=progress):
            done = subprocess.run(command, capture_output=True, text=True)
        if done.returncode != 0:
            raise RuntimeError(f"{compiler} failed ({done.returncode}) on {source.name}: {done.stderr[-2000:]}")
        os.replace(out, library)


def load_or_make(name: str, functions: Sequence[ca.Function], make: Callable[[list[ca.Function]], ca.Function],
                 solver_options: str, fixed_inputs: Sequence[str] = (), external_options: dict | None = None,
                 progress: Callable[[str], None] | None = None) -> ca.Function | None:
    """The solver `make` builds on the compiled `functions`, from the cache or made and cached now.

    Parameters
    ----------
    name : str
        The solver's name (the cache files are named after it).
    functions : sequence of casadi.Function
        The SX functions to compile (each becomes an ``external`` of the same name).
    make : callable
        ``make(externals) -> solver``: builds the solver on the loaded externals, in the order of `functions`.
    solver_options : str
        What `make` depends on beyond the functions (its options, dimensions), as text: part of the cache key.
    fixed_inputs : sequence of str
        Inputs of `functions` that the solver never differentiates by (no derivative code is written for them).
    external_options : dict, optional
        Options of each ``external`` (e.g. its Jacobian penalty), as the interpreted functions had them.
    progress : callable, optional
        Where a first build's lines go (default :func:`flexarm.progress.say`).

    Returns
    -------
    casadi.Function or None
        None when no C compiler is found, or compiled solvers are turned off: the caller makes its interpreted
        solver.
    """
    progress = say if progress is None else progress
    compiler = c_compiler()
    if compiler is None:
        return None
    folder = cache_folder() / entry_key(name, functions, solver_options, compiler)
    solver_file, library = folder / f"{name}.casadi", folder / f"{name}{_library_suffix()}"
    if solver_file.exists() and library.exists():
        try:
            solver = ca.Function.load(str(solver_file))
            _mark_used(solver_file)
            return solver
        except RuntimeError as exc:  # a file from another CasADi build, or damaged: made again below
            progress(f"{solver_file} did not load ({str(exc).splitlines()[0][:200]}); making it again")
    try:
        folder.mkdir(parents=True, exist_ok=True)
        if not library.exists():
            _compile(functions, fixed_inputs, library, compiler, progress)
    except OSError as exc:  # an unwritable cache folder: the interpreted solver, as without a compiler
        progress(f"the compiled-solver cache {folder} cannot be written ({exc}); the {name} solver runs "
                 f"interpreted (set ${CACHE_VARIABLE} to a writable folder)")
        return None
    externals = [ca.external(f.name(), str(library), dict(external_options or {})) for f in functions]
    progress(f"making the {name} solver on the compiled functions, once for this machine (about 10 CPU-s)")
    with heartbeat(f"making the {name} solver", emit=progress):
        solver = make(externals)
    tmp = None
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{name}.", suffix=".casadi", dir=folder)
        os.close(fd)
        solver.save(tmp)
        os.replace(tmp, solver_file)
        progress(f"cached in {folder}")
        for old in prune(name, keep=folder):
            progress(f"removed {old}, an older {name} solver (the cache keeps the {KEEP_ENTRIES} used last)")
    except (OSError, RuntimeError) as exc:  # a full disk: this process still has its solver
        progress(f"the {name} solver was not cached in {folder} ({exc}); it is made again next time")
    finally:
        if tmp is not None and os.path.exists(tmp):
            os.unlink(tmp)
    return solver


def _mark_used(solver_file: Path) -> None:
    try:
        os.utime(solver_file)
    except OSError:  # a read-only cache: its entries are never pruned by this process either
        pass


def prune(name: str, keep: Path | None = None) -> list[Path]:
    """Remove the `name` solver's cache entries beyond the :data:`KEEP_ENTRIES` used last (the modification time
    of their solver file, which a load renews); `keep` is never removed. Returns the removed folders."""
    root = cache_folder()
    try:
        entries = [f.parent for f in root.glob(f"*/{name}.casadi") if f.parent != keep]
        entries.sort(key=lambda e: (e / f"{name}.casadi").stat().st_mtime, reverse=True)
    except OSError:
        return []
    removed = []
    for entry in entries[KEEP_ENTRIES - (keep is not None):]:
        shutil.rmtree(entry, ignore_errors=True)
        if not entry.exists():
            removed.append(entry)
    return removed
