"""Python FMUs isolated from each other in one process (issue 21, item 4).

Every Python FMU bundles its code under module names private to its build
(fmu_build/isolate.py), so any number of them, of any builds, in any load order,
next to a user's own pythonfmu FMU, each run their own code on their own data.
The host is tests/fmi_loop_host.py in a fresh process with a clean environment:
no repository on ``sys.path``, nothing of this project imported.
"""

from __future__ import annotations

import ast
import itertools
import json
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmu_harness import built_fmus
from native_fmus import native_fmus

from scenarios.metrics import table_metrics
from scenarios.run.setup import desired_states, desired_trajectory

HOST = Path(__file__).resolve().parent / "fmi_loop_host.py"
TRIO = ("plant", "sensors", "controller")

# A user's own pythonfmu FMU, loaded first, whose resources hold unrelated modules named like ours.
_USER_SLAVE = '''
from pythonfmu import Fmi2Causality, Fmi2Slave, Real

import flexarm  # the user's own package of that name (resources/flexarm), nothing to do with ours
import flexarm_fmu_base  # and a module named like our glue


class UserCounter(Fmi2Slave):
    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.count = float(flexarm.START + flexarm_fmu_base.OFFSET)
        self.register_variable(Real("count", causality=Fmi2Causality.output))

    def do_step(self, current_time, step_size):
        self.count += 1.0
        return True
'''


def clean_env() -> dict[str, str]:
    """The environment of a host that knows nothing of this project (no PYTHONPATH)."""
    return {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "PYTHONSTARTUP")}


def run_host(spec: dict, tmp_path: Path, name: str = "host", env: dict | None = None) -> dict[str, np.ndarray]:
    """Run tests/fmi_loop_host.py on `spec` in a fresh process (clean environment plus `env`, cwd outside the
    repo)."""
    spec_file, out = tmp_path / f"{name}.json", tmp_path / f"{name}.npz"
    spec_file.write_text(json.dumps(spec))
    proc = subprocess.run([sys.executable, str(HOST), str(spec_file), str(out)], capture_output=True, text=True,
                          env={**clean_env(), **(env or {})}, cwd=tmp_path, timeout=1200)
    assert proc.returncode == 0, proc.stderr[-4000:]
    with np.load(out) as z:
        return {k: z[k] for k in z.files}


def rms_position_error(result: dict, run: int) -> float:
    theta = result[f"run{run}_theta"]
    desired = desired_states(desired_trajectory(), len(theta), 1e-3)
    return table_metrics(result[f"run{run}_tau"], theta, result[f"run{run}_omega"], desired["theta"],
                         desired["omega"])["rms_position_error"]


@pytest.fixture(scope="module")
def user_fmu(tmp_path_factory) -> Path:
    """A user's pythonfmu FMU with its own ``flexarm`` package and ``flexarm_fmu_base`` module."""
    from pythonfmu.builder import FmuBuilder

    src = tmp_path_factory.mktemp("user_fmu")
    (src / "user_counter.py").write_text(_USER_SLAVE)
    (src / "flexarm").mkdir()
    (src / "flexarm" / "__init__.py").write_text("START = 100\n")
    (src / "flexarm_fmu_base.py").write_text("OFFSET = 5\n")
    saved_path, saved = list(sys.path), {k: sys.modules.get(k) for k in ("flexarm", "flexarm_fmu_base",
                                                                          "user_counter")}
    try:
        for k in saved:
            sys.modules.pop(k, None)
        out = FmuBuilder.build_FMU(src / "user_counter.py", dest=src / "out",
                                   project_files=[src / "flexarm", src / "flexarm_fmu_base.py"])
    finally:
        sys.path[:] = saved_path
        for k, v in saved.items():
            sys.modules.pop(k, None)
            if v is not None:
                sys.modules[k] = v
    return Path(out)


def test_every_module_of_a_python_fmu_has_a_name_private_to_its_build():
    """No bundled module is called flexarm*, every import of one is rewritten, and no two FMUs share a name."""
    seen: dict[str, str] = {}
    for name, fmu in built_fmus().items():
        with zipfile.ZipFile(fmu) as z:
            manifest = json.loads(z.read("resources/flexarm_bundle.json"))
            names = manifest["modules"]
            assert set(names) >= {"flexarm", "flexarm_fmu_base", "flexarm_fmu_preflight"}, name
            assert z.read("resources/slavemodule.txt").decode().strip() == manifest["slave_module"]
            assert manifest["package"] == names["flexarm"]
            tops = {m.split("/")[1].removesuffix(".py") for m in z.namelist()
                    if m.startswith("resources/") and m.count("/") >= 1 and (m.endswith(".py") or m.count("/") > 1)}
            ours = {t for t in tops if "flexarm" in t}
            assert ours == set(names.values()), (name, ours ^ set(names.values()))
            for private in names.values():
                assert private not in seen, (private, seen.get(private), name)
                seen[private] = name
            for member in z.namelist():
                if not (member.endswith(".py") and member.startswith("resources/_flexarm")):
                    continue
                tree = ast.parse(z.read(member).decode(), member)
                for node in ast.walk(tree):
                    modules = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                        [node.module] if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module else []
                    for m in modules:
                        assert m.split(".")[0] not in names, f"{name}: {member} imports {m}"


def test_python_fmus_in_every_load_order_next_to_a_user_fmu_equal_the_native_kind(user_fmu, tmp_path):
    """Issue 21 acceptance: plant, sensors and controller (Python) in all 6 load orders in one fresh process that
    never imported flexarm, a user's pythonfmu FMU with its own 'flexarm' loaded first: every order gives the
    native kind's rms position error (nothing set, Table 2 'none'), and the user's FMU keeps its own modules."""
    python, native = built_fmus(), native_fmus()
    traj = desired_trajectory()
    n = int(round(float(traj.t[-1] - traj.t[0]) / 1e-3))
    orders = list(itertools.permutations(TRIO))
    runs = [{"fmus": {k: str(native[k]) for k in TRIO}, "n_steps": n}]
    runs += [{"fmus": {k: str(python[k]) for k in TRIO}, "n_steps": n, "load_order": list(order),
              "extra": {"user": str(user_fmu)}} for order in orders]
    result = run_host({"runs": runs}, tmp_path)
    modules = set(result["modules"].tolist())
    assert "flexarm" in modules and "flexarm_fmu_base" in modules  # the user's own, loaded first: still there
    assert not any(m.startswith("flexarm.") for m in modules)  # nothing of ours under the public name
    assert np.all(result["run1_user_count"] == 105.0 + np.arange(n + 1))  # the user's FMU ran its own code
    reference = rms_position_error(result, 0)
    print(f"\nnative: rms position error {reference:.6g} deg")
    for i, order in enumerate(orders, start=1):
        rms = rms_position_error(result, i)
        print(f"python, load order {' -> '.join(order)}: {rms:.6g} deg")
        assert rms == pytest.approx(reference, rel=1e-6), order
        np.testing.assert_allclose(result[f"run{i}_theta"], result["run0_theta"], rtol=0, atol=1e-9)
    assert reference < 0.01  # the paper's tracking (Table 2 'none'), not a failed start


def test_numba_kernels_compile_once_per_build_not_per_unpacking(tmp_path):
    """The Python plant FMU's kernels are cached per FMU build (flexarm/_numba_cache.py): a second process,
    which unpacks the same FMU into a new folder, writes nothing to the cache (compiles nothing) and steps the
    same; the cache folder is named after the build's private package."""
    python = built_fmus()
    cache = tmp_path / "cache"
    spec = {"runs": [{"fmus": {k: str(python[k]) for k in TRIO}, "n_steps": 20}]}

    def cached_files() -> dict[str, tuple[int, int]]:
        return {str(p.relative_to(cache)): (p.stat().st_mtime_ns, p.stat().st_size)
                for p in cache.rglob("*") if p.is_file()}

    first = run_host(spec, tmp_path, "first", env={"XDG_CACHE_HOME": str(cache)})
    after_first = cached_files()
    with zipfile.ZipFile(python["plant"]) as z:
        package = json.loads(z.read("resources/flexarm_bundle.json"))["package"]
    assert any(f.startswith(f"flexarm-fmi/numba/{package}/") and f.endswith(".nbi") for f in after_first), \
        sorted(after_first)[:5]
    second = run_host(spec, tmp_path, "second", env={"XDG_CACHE_HOME": str(cache)})
    assert cached_files() == after_first  # nothing compiled, nothing rewritten
    np.testing.assert_array_equal(second["run0_theta"], first["run0_theta"])
