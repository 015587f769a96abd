"""Stage, build, finish and validate one FMU; build them all.

Each FMU is built with pythonfmu's builder and carries, in its ``resources``,
only what it needs at run time:

* its slave script and the glue ``fmus/common/*.py``;
* the ``flexarm`` modules the slave imports when it is loaded, initialised and
  stepped (traced in a subprocess: no optimiser or CasADi code), and the data
  files its :class:`~fmu_build.registry.FmuSpec` names (only its own gain files;
  no figures);
* pythonfmu's run-time modules (not its builder), with an ``__init__`` that
  imports no builder;
* ``flexarm_bundle.json``: the private module names (below), SHA-256 of the bundled
  ``flexarm`` and of every bundled data file, which the FMU checks when it is
  instantiated (the glue's ``flexarm_fmu_preflight.py``).

Every top-level module and package of an FMU (``flexarm``, the glue, the slave)
is bundled under a name private to that FMU build (:mod:`fmu_build.isolate`:
``_flexarm_<fmu>_<digest>``, imports rewritten), so any number of our FMUs, of
any builds, in any load order, share one interpreter and each runs its own code
on its own data (``resources/_flexarm_<fmu>_<digest>/data``).

Before bundling, the data's recorded SHA-256 chain (gain files → trajectory and
parameter file, trajectory → parameter file) must verify. Afterwards the FMU's
binary becomes the C front end (:mod:`fmu_build.compile`), pythonfmu's binary
moves beside it as ``libpythonfmu-export.so``, ``documentation/`` is generated,
``fmpy.validation.validate_fmu`` must find no problem, and the file is renamed
into place with mode 0644 (under the umask).
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import importlib
import json
import os
import re
import runpy
import shutil
import subprocess
import sys
import tempfile
import uuid
import zipfile
from dataclasses import dataclass
from pathlib import Path
from xml.etree import ElementTree

from .compile import BuildError, c_compiler, check_platform, compile_shim
from .docs import render_documentation
from .isolate import build_digest, private_name, rewrite_tree
from .progress import heartbeat, say
from .registry import COMMON_DIR, DOC_FILE, FLEXARM_DIR, FMUS, SHIM_FILES, SOURCES, FmuSpec, default_out_dir

#: The pythonfmu version whose internals the glue works around (fmus/common/flexarm_fmu_pythonfmu.py).
PYTHONFMU_VERSION = "0.7.0"
#: pythonfmu's own binary inside the FMU (loaded by the front end from its folder).
INNER_BINARY = "libpythonfmu-export.so"
#: pythonfmu modules the FMU needs at run time (the builder, CSV and deploy tools stay out).
PYTHONFMU_RUNTIME = ("__init__.py", "_version.py", "default_experiment.py", "enums.py", "fmi2slave.py", "logmsg.py",
                     "variables.py")
_PYTHONFMU_INIT = '''"""pythonfmu's run-time part, as bundled by flexarm-fmi (the builder is not in the FMU)."""
from ._version import __version__
from .default_experiment import DefaultExperiment
from .enums import Fmi2Causality, Fmi2Initial, Fmi2Variability
from .fmi2slave import Fmi2Slave
from .variables import Boolean, Integer, Real, String
'''
#: Capabilities written into <CoSimulation> (pythonfmu option names).
FMU_OPTIONS = {
    "canHandleVariableCommunicationStepSize": True,
    "canGetAndSetFMUstate": True,
    "canSerializeFMUstate": True,
}
#: Every member's timestamp in the archives we write: the same inputs give the same bytes.
ZIP_DATE = (2024, 1, 1, 0, 0, 0)
#: pythonfmu writes a time-based GUID and the build's date and time: two builds of the same sources would differ in
#: every byte that carries them (the description, the front end the GUID is compiled into, the documentation).
_GUID_ATTR = re.compile(r'\sguid="([^"]*)"')
_DATE_ATTR = re.compile(r'\sgenerationDateAndTime="[^"]*"')
#: The namespace of the FMUs' content-derived GUIDs (uuid5).
_GUID_NAMESPACE = uuid.UUID("5f0c7c52-7d3e-4c43-9a55-0c1f3c8a7e21")


def reproducible_description(raw: zipfile.ZipFile) -> str:
    """pythonfmu's modelDescription.xml made a function of the FMU's content: no generationDateAndTime (optional
    in FMI 2.0), and a GUID derived from the description and every member kept (uuid5 of their SHA-256), so it
    changes when the FMU does and only then."""
    text = raw.read("modelDescription.xml").decode("utf-8")
    text = _DATE_ATTR.sub("", text, count=1)
    digest = hashlib.sha256(_GUID_ATTR.sub(' guid=""', text, count=1).encode())
    for name in sorted(n for n in raw.namelist() if _keep(n) and n != "modelDescription.xml"):
        digest.update(name.encode() + b"\0" + hashlib.sha256(raw.read(name)).digest())
    guid = str(uuid.uuid5(_GUID_NAMESPACE, digest.hexdigest()))
    return _GUID_ATTR.sub(f' guid="{guid}"', text, count=1)


@functools.lru_cache(maxsize=1)
def _glue() -> dict[str, dict]:
    """The glue's standard-library helpers (``flexarm_fmu_preflight.py``) as the build runs them."""
    return {"preflight": runpy.run_path(str(COMMON_DIR / "flexarm_fmu_preflight.py"))}


def check_pythonfmu() -> None:
    """BuildError unless the installed pythonfmu is exactly :data:`PYTHONFMU_VERSION`."""
    try:
        from importlib.metadata import version

        found = version("pythonfmu")
    except Exception as exc:  # noqa: BLE001 - not installed, or unreadable metadata
        raise BuildError(f"pythonfmu is not installed ({exc}); pip install pythonfmu=={PYTHONFMU_VERSION}") from None
    if found != PYTHONFMU_VERSION:
        raise BuildError(f"pythonfmu {found} is installed, but the FMUs are built with pythonfmu=={PYTHONFMU_VERSION} "
                         "exactly: the glue works around that version's internals (fmus/common/"
                         f"flexarm_fmu_pythonfmu.py); pip install pythonfmu=={PYTHONFMU_VERSION}")


def check_data_chain() -> None:
    """BuildError if a data file's recorded SHA-256 of its inputs does not verify (nothing is bundled then)."""
    problems = _glue()["preflight"]["data_chain_problems"](FLEXARM_DIR / "data")
    if problems:
        raise BuildError("the data's SHA-256 chain does not verify, so no FMU is built:\n  " + "\n  ".join(problems))


def bundle_files(package_dir: Path) -> list[Path]:
    """Files of a folder that may go into an FMU (the glue's rule: no caches, compiled or hidden files)."""
    return _glue()["preflight"]["bundle_files"](package_dir)


def tree_sha256(package_dir: Path) -> str:
    """SHA-256 identifying a copy of a package (the glue's rule, which the FMU checks at instantiation)."""
    return _glue()["preflight"]["tree_sha256"](package_dir)


_TRACE = """
import importlib, json, sys


class NoOptimiser:  # the FMUs carry no optimiser: a module that needs CasADi is left out
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] == "casadi":
            raise ImportError("casadi is not available inside an FMU")


sys.meta_path.insert(0, NoOptimiser())
sys.path[:0] = {paths!r}
module = importlib.import_module({module!r})
base = sys.modules["flexarm_fmu_base"].FlexarmSlave
cls = next(c for c in vars(module).values()
           if isinstance(c, type) and issubclass(c, base) and c.__module__ == module.__name__)
slave = cls(instance_name="trace", resources=None)
slave.setup_experiment(0.0)
slave.enter_initialization_mode()
slave.exit_initialization_mode()
slave.do_step(0.0, 1e-3)
print(json.dumps(sorted(m.__file__ for n, m in sys.modules.items()
                        if (n == "flexarm" or n.startswith("flexarm.")) and getattr(m, "__file__", None))))
"""


def flexarm_modules(spec: FmuSpec) -> list[Path]:
    """The ``flexarm`` source files the slave imports when loaded, initialised and stepped once (a subprocess)."""
    # The glue, the slave's folder, and the flexarm this build bundles (first, ahead of any other install).
    paths = [str(p) for p in _import_paths(spec)] + [str(FLEXARM_DIR.parent)]
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    proc = subprocess.run([sys.executable, "-c", _TRACE.format(paths=paths, module=spec.script.stem)],
                          capture_output=True, text=True, env=env, cwd=tempfile.gettempdir(), timeout=600)
    if proc.returncode != 0:
        raise BuildError(f"{spec.name}: loading the slave to find the modules it needs failed:\n{proc.stderr[-3000:]}")
    files = [Path(f).resolve() for f in json.loads(proc.stdout.strip().splitlines()[-1])]
    outside = [f for f in files if not f.is_relative_to(FLEXARM_DIR)]
    if outside:
        raise BuildError(f"{spec.name}: flexarm modules imported from outside {FLEXARM_DIR}: {outside}")
    return sorted(set(files) | {FLEXARM_DIR / "__init__.py"})


def all_flexarm_modules() -> list[Path]:
    """The union of :func:`flexarm_modules` over every FMU: what each FMU bundles.

    Each FMU imports only its own copy (private module names, :mod:`fmu_build.isolate`); the union
    keeps a module that a parameter value imports lazily (not seen by the one-step trace) in every FMU.
    """
    if not _ALL_MODULES:
        _ALL_MODULES.extend(sorted({f for spec in FMUS.values() for f in flexarm_modules(spec)}))
    return list(_ALL_MODULES)


_ALL_MODULES: list[Path] = []


def data_files(spec: FmuSpec) -> list[Path]:
    """The data files of the spec (glob patterns under flexarm/data); BuildError if a pattern matches nothing."""
    data = FLEXARM_DIR / "data"
    out = []
    for pattern in spec.data:
        found = sorted(p for p in data.glob(pattern) if p.is_file())
        if not found:
            raise BuildError(f"{spec.name}: no data file matches {pattern!r} in {data}")
        out += [p for p in found if p not in out]
    return out


def _import_paths(spec: FmuSpec) -> list[Path]:
    # Folders of extra modules too: importing the script may import them.
    return [COMMON_DIR, spec.script.parent, *[e.parent for e in spec.extra_files if e.suffix == ".py"]]


@contextlib.contextmanager
def import_sandbox(paths: list[Path], private: set[str] = frozenset()):
    """Let pythonfmu import the slave script, then undo sys.path and sys.modules changes.

    Without this, a later in-process load of the built FMU would find the
    project's copy of the slave module already in ``sys.modules`` instead
    of the one bundled in the FMU. `private`: the private module names of the FMU being
    built (:mod:`fmu_build.isolate`), dropped from ``sys.modules`` afterwards with their submodules.
    """
    saved_path = list(sys.path)
    ours = {p.stem for p in SOURCES.glob("*/*.py")}
    # Those of FMUs already loaded in this process would shadow the project's sources (and an earlier unpacking
    # of this very build, its folder perhaps deleted since, the staged copy): set them aside while building, and
    # put them back afterwards for those FMUs' sake.
    shadowing = {name: sys.modules.pop(name) for name in list(sys.modules)
                 if name in ours or name.split(".")[0] in private}
    sys.path[:0] = [str(p) for p in paths]
    try:
        yield
    finally:
        sys.path[:] = saved_path
        for name in ours & set(sys.modules):
            del sys.modules[name]
        for name in [n for n in sys.modules if n.split(".")[0] in private]:
            del sys.modules[name]
        sys.modules.update(shadowing)


def _slave_class(module):
    """The FlexarmSlave subclass a slave module defines (the one pythonfmu instantiates)."""
    base = sys.modules["flexarm_fmu_base"].FlexarmSlave
    found = [c for c in vars(module).values()
             if isinstance(c, type) and issubclass(c, base) and c.__module__ == module.__name__]
    if len(found) != 1:
        raise BuildError(f"{module.__name__}: expected one FlexarmSlave subclass, found {[c.__name__ for c in found]}")
    return found[0]


def interfaces() -> dict[str, dict]:
    """Every FMU's interface from its slave class: {name: {"cls", "docs", "variables"}}."""
    out = {}
    for name, spec in FMUS.items():
        with import_sandbox(_import_paths(spec)):
            module = importlib.import_module(spec.script.stem)
            cls = _slave_class(module)
            defining = sys.modules[next(k.__module__ for k in cls.__mro__ if "VARIABLES" in vars(k))]
            docs = [d for d in dict.fromkeys((module.__doc__, defining.__doc__)) if d]
            out[name] = {"cls": cls, "docs": docs, "variables": tuple(cls.VARIABLES)}
    return out


def _shared_sources() -> list[Path]:
    """The files every FMU may be made from: the glue, the C front end, flexarm and the build tooling."""
    return [*sorted(COMMON_DIR.glob("*.py")), *SHIM_FILES, *bundle_files(FLEXARM_DIR),
            *bundle_files(Path(__file__).parent), *([DOC_FILE] * DOC_FILE.is_file())]


def _newest(paths) -> float:
    return max((p.stat().st_mtime for p in paths), default=0.0)


def is_up_to_date(spec: FmuSpec, fmu: Path, shared_newest: float | None = None) -> bool:
    """True if `fmu` exists and is newer than every source (and the build tooling).

    `shared_newest`: the newest modification time of :func:`_shared_sources`, when the caller checks several
    FMUs at once (:func:`build_all` walks those folders once, not once per FMU: issue 34, start-up).
    """
    if not fmu.is_file():
        return False
    shared = _newest(_shared_sources()) if shared_newest is None else shared_newest
    return fmu.stat().st_mtime >= max(shared, _newest([spec.script, *spec.extra_files]))


@functools.lru_cache(maxsize=1)
def _slew() -> dict[str, float]:
    """The trajectory facts the FMUs' defaults come from (the glue's ``slew()``, run from the project's data)."""
    with import_sandbox([COMMON_DIR]):
        return importlib.import_module("flexarm_fmu_base").slew()


@dataclass
class Staged:
    """An FMU's project files, laid out under their private names (:mod:`fmu_build.isolate`)."""

    #: the slave script under its private name (what pythonfmu builds from)
    script: Path
    #: everything else pythonfmu puts into ``resources`` (the private package, the manifest, the glue)
    project_files: list[Path]
    #: top-level module name -> private name
    names: dict[str, str]


def stage(spec: FmuSpec, folder: Path) -> Staged:
    """Lay out the FMU's files in `folder` under private module names (:mod:`fmu_build.isolate`).

    The ``flexarm`` modules and data the FMU needs, the glue and the slave script are copied, every
    top-level name among them gets the private name of this build (``flexarm`` ->
    ``_flexarm_<fmu>_<digest>``, ``flexarm_fmu_base`` -> ``_flexarm_fmu_base_<fmu>_<digest>``, ...), their
    imports are rewritten to match, and ``flexarm_bundle.json`` records the names.
    """
    folder.mkdir(parents=True, exist_ok=True)
    flexarm = folder / "flexarm"
    for src in [*all_flexarm_modules(), *data_files(spec)]:
        dest = flexarm / src.relative_to(FLEXARM_DIR)
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(src, dest)
    modules = [*sorted(COMMON_DIR.glob("*.py")), *[e for e in spec.extra_files if e.suffix == ".py"], spec.script]
    others = [e for e in spec.extra_files if e.suffix != ".py"]
    for f in [*modules, *others]:
        shutil.copy2(f, folder / f.name)
    digest = build_digest(spec.name, [*bundle_files(flexarm), *[folder / f.name for f in [*modules, *others]]],
                          folder)
    names = {"flexarm": private_name("flexarm", spec.name, digest)}
    names.update({f.stem: private_name(f.stem, spec.name, digest) for f in modules})
    rewrite_tree(bundle_files(flexarm), names, literals=False)
    rewrite_tree([folder / f.name for f in modules], names)
    package = folder / names["flexarm"]
    flexarm.rename(package)
    renamed = {f.stem: (folder / f.name).rename(folder / f"{names[f.stem]}.py") for f in modules}
    manifest = folder / _glue()["preflight"]["BUNDLE_MANIFEST"]
    data_dir = package / "data"
    manifest.write_text(json.dumps({
        "fmu": spec.name, "slave_module": names[spec.script.stem], "package": names["flexarm"],
        "modules": names, "preflight": f"{names['flexarm_fmu_preflight']}.py",
        "flexarm_sha256": tree_sha256(package),
        "flexarm_files": [f.relative_to(package).as_posix() for f in bundle_files(package)],
        "data_sha256": {f.relative_to(data_dir).as_posix(): hashlib.sha256(f.read_bytes()).hexdigest()
                        for f in bundle_files(data_dir)},
        "shim_sha256": {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in SHIM_FILES},
        "slew": _slew(),
    }, indent=1))
    glue = [renamed[f.stem] for f in modules if f != spec.script]
    return Staged(renamed[spec.script.stem], [package, manifest, *glue, *[folder / f.name for f in others]], names)


def build_fmu(spec: FmuSpec, out_dir: Path, peers: dict[str, dict] | None = None) -> Path:
    """Build one FMU into ``out_dir/<spec.name>.fmu`` (temporary file, finish, validate, rename).

    `peers` (from :func:`interfaces`) names the other FMUs in the generated
    documentation's connection table; computed if not given.
    """
    from fmpy.validation import validate_fmu
    from pythonfmu.builder import FmuBuilder

    check_platform()
    check_pythonfmu()
    c_compiler()  # fail before building anything
    check_data_chain()
    peers = interfaces() if peers is None else peers
    out_dir.mkdir(parents=True, exist_ok=True)
    final = out_dir / f"{spec.name}.fmu"
    with tempfile.TemporaryDirectory(prefix=f"build_{spec.name}_") as tmp:
        work = Path(tmp)
        staged = stage(spec, work / "stage")
        raw_fmu = work / "pythonfmu.fmu"
        fd, tmp_name = tempfile.mkstemp(dir=out_dir, prefix=f".{spec.name}-", suffix=".fmu")
        os.close(fd)
        tmp_fmu = Path(tmp_name)
        try:
            with import_sandbox([staged.script.parent], private=set(staged.names.values())):
                FmuBuilder.build_FMU(staged.script, dest=raw_fmu, project_files=staged.project_files, **FMU_OPTIONS)
            finish_fmu(raw_fmu, tmp_fmu, spec, peers, work, preflight=f"{staged.names['flexarm_fmu_preflight']}.py")
            problems = validate_fmu(str(tmp_fmu))
            if problems:
                raise BuildError(f"{spec.name}: fmpy.validate_fmu found {len(problems)} problem(s):\n  "
                                 + "\n  ".join(problems))
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(tmp_fmu, 0o644 & ~umask)  # mkstemp's 0600 would make the FMU private; never group-writable
            os.replace(tmp_fmu, final)
        finally:
            tmp_fmu.unlink(missing_ok=True)
    return final


def _keep(name: str) -> bool:
    """Members of pythonfmu's FMU that go into ours (binaries, documentation and pythonfmu tools are redone)."""
    if name.startswith(("binaries/", "documentation/")):
        return False
    if name.startswith("resources/pythonfmu/"):
        return name.rsplit("/", 1)[-1] in PYTHONFMU_RUNTIME
    return True


def finish_fmu(raw_fmu: Path, dest: Path, spec: FmuSpec, peers: dict[str, dict], work: Path,
               preflight: str = "flexarm_fmu_preflight.py") -> None:
    """Turn pythonfmu's FMU into ours: the front end as the FMU's binary, pythonfmu's beside it, documentation.

    `preflight`: the file name of the start-up check in ``resources`` that the front end runs.
    """
    with zipfile.ZipFile(raw_fmu) as raw:
        description = reproducible_description(raw)
        md = ElementTree.fromstring(description.encode("utf-8"))
        cosim = md.find("CoSimulation")
        model_id, guid = cosim.get("modelIdentifier"), md.get("guid")
        inner = raw.read(f"binaries/linux64/{model_id}.so")
        shim = compile_shim(guid, model_id, work / f"{model_id}.so", preflight).read_bytes()
        page = render_documentation(spec.name, md, peers)
        with zipfile.ZipFile(dest, "w", zipfile.ZIP_DEFLATED) as out:
            def put(name: str, data: bytes, mode: int = 0o644) -> None:
                info = zipfile.ZipInfo(name, date_time=ZIP_DATE)
                info.external_attr = mode << 16
                out.writestr(info, data, zipfile.ZIP_DEFLATED)

            for info in raw.infolist():
                if info.filename == "modelDescription.xml":
                    put(info.filename, description.encode("utf-8"))
                elif _keep(info.filename):
                    put(info.filename, _PYTHONFMU_INIT.encode() if info.filename == "resources/pythonfmu/__init__.py"
                        else raw.read(info))
            put(f"binaries/linux64/{model_id}.so", shim, 0o755)
            put(f"binaries/linux64/{INNER_BINARY}", inner, 0o755)
            put("documentation/index.html", page.encode())
            if DOC_FILE.is_file():
                put(f"documentation/{DOC_FILE.name}", DOC_FILE.read_bytes())


def build_all(out_dir: str | os.PathLike | None = None, only=None, force: bool = False) -> dict[str, Path]:
    """Build the project's FMUs; return {name: path of the .fmu}.

    Parameters
    ----------
    out_dir : path-like, optional
        Output folder (default :func:`fmu_build.registry.default_out_dir`: ``$FLEXARM_FMU_DIR``,
        else ``build/fmus`` under the current directory).
    only : str or iterable of str, optional
        Names from :data:`fmu_build.registry.FMUS` to build (default: all).
    force : bool
        Rebuild even if the FMU is newer than all its sources.
    """
    out_dir = Path(out_dir) if out_dir is not None else default_out_dir()
    names = list(FMUS) if only is None else ([only] if isinstance(only, str) else list(only))
    unknown = [n for n in names if n not in FMUS]
    if unknown:
        raise BuildError(f"unknown FMU name(s) {unknown}; choose from {sorted(FMUS)}")
    result, peers = {}, None
    shared_newest = None if force else _newest(_shared_sources())
    for name in names:
        spec = FMUS[name]
        target = out_dir / f"{name}.fmu"
        if not force and is_up_to_date(spec, target, shared_newest):
            result[name] = target
            continue
        peers = interfaces() if peers is None else peers  # once per build, for the documentation
        say(f"building {name}.fmu into {out_dir} (Python FMU: compile its C front end, trace and bundle its "
            f"modules; about 10-20 s)")
        with heartbeat(f"building {name}.fmu"):  # the first build on a machine also builds Zig's C libraries
            result[name] = build_fmu(spec, out_dir, peers)
    return result
