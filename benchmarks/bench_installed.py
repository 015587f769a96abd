"""Every documented command, from an installed package (``pip install .``, not a checkout): works or refuses, how fast.

    python benchmarks/bench_installed.py                 # install into a temporary venv, run each command
    python benchmarks/bench_installed.py --timeout 300   # let the commands that work run longer
    python benchmarks/bench_installed.py --only results-page regenerate   # the commands containing these

Collects every command quoted in README.md and docs/*.md (``python -m ...``, ``flexarm-build-fmus ...``,
``python build_fmus.py ...``), installs this checkout with ``pip install .`` into a fresh venv that sees the
system's packages (``--system-site-packages --no-deps``: the project, not its dependencies, is what is
measured), and runs each command in an empty folder outside the checkout, with stdin closed. It prints, per
command: the exit code, the wall time, its CPU time, and what it said first on stdout (the refusal, for a
command that failed). A command
that exits 0 works; one that exits non-zero should say why within a second (issue 23: "works or refuses in
under a second with a reason"). Commands with placeholders (``...``, ``[--native]``, ``MyController.fmu``) are
listed as templates and not run. A command still running at ``--timeout`` is stopped and reported as such.
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
_QUOTED = re.compile(r"`((?:python3? -m |python3? build_fmus\.py|flexarm-build-fmus)[^`]*)`")
_TEMPLATE = re.compile(r"\.\.\.|\[|\]|MyController|<")


def documented_commands() -> list[str]:
    """Every distinct command quoted in README.md and docs/*.md, in first-seen order."""
    seen: dict[str, None] = {}
    for doc in [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]:
        for m in _QUOTED.finditer(doc.read_text(encoding="utf-8")):
            seen.setdefault(" ".join(m.group(1).split()), None)
    return list(seen)


def _children_cpu() -> float:
    """CPU seconds of the finished child processes (a busy machine inflates wall time, not this)."""
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def install(venv: Path) -> Path:
    """A venv with this checkout installed (not editable); its python."""
    subprocess.run([sys.executable, "-m", "venv", "--system-site-packages", str(venv)], check=True)
    python = venv / "bin" / "python"
    t0 = time.perf_counter()
    subprocess.run([str(python), "-m", "pip", "install", "--quiet", "--no-deps", str(REPO)], check=True,
                   stdout=subprocess.DEVNULL)
    print(f"installed {REPO.name} into {venv} with `pip install .` in {time.perf_counter() - t0:.0f} s")
    return python


def run(command: str, python: Path, cwd: Path, timeout: float) -> tuple[str, float, str]:
    """(exit code or 'timeout', wall time in s, first line said) of one command."""
    argv = shlex.split(command)
    if argv[0] in ("python", "python3"):
        argv[0] = str(python)
    else:
        argv[0] = str(python.parent / argv[0])
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    t0 = time.perf_counter()
    cpu0 = _children_cpu()
    try:
        p = subprocess.run(argv, cwd=cwd, env=env, stdin=subprocess.DEVNULL, capture_output=True, text=True,
                           timeout=timeout)
    except subprocess.TimeoutExpired:
        return "timeout", time.perf_counter() - t0, f"still running after {timeout:.0f} s (stopped)"
    wall = time.perf_counter() - t0
    cpu = _children_cpu() - cpu0
    said = [ln.strip() for ln in (p.stderr + "\n" + p.stdout).splitlines() if ln.strip()]
    if p.returncode != 0:  # the refusal is the last line that says something (a traceback ends with it)
        said = [ln for ln in said if ln.lower().startswith(("error", "refused")) or "error" in ln.lower()] or said
        first = said[-1] if said else "(said nothing)"
    else:
        first = said[0] if said else "(said nothing)"
    return str(p.returncode), wall, f"[CPU {cpu:.2f} s] {first[:150]}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--timeout", type=float, default=180.0, help="seconds per command (default 180)")
    ap.add_argument("--only", nargs="+", help="run only the commands containing one of these texts")
    args = ap.parse_args(argv)
    commands = [c for c in documented_commands() if not args.only or any(o in c for o in args.only)]
    with tempfile.TemporaryDirectory(prefix="flexarm-installed-") as tmp:
        python = install(Path(tmp) / "venv")
        rows = []
        for command in commands:
            if _TEMPLATE.search(command):
                rows.append((command, "-", None, "template (placeholders), not run"))
                continue
            cwd = Path(tempfile.mkdtemp(dir=tmp, prefix="cwd-"))
            code, wall, said = run(command, python, cwd, args.timeout)
            rows.append((command, code, wall, said))
            print(f"{code:>7}  {wall:7.2f} s  {command}\n{'':19}{said}", flush=True)
    slow = [r for r in rows if r[1] not in ("0", "-") and (r[2] or 0) >= 1.0]
    print(f"\n{len(rows)} documented commands: {sum(r[1] == '0' for r in rows)} worked, "
          f"{sum(r[1] not in ('0', '-', 'timeout') for r in rows)} refused, "
          f"{sum(r[1] == 'timeout' for r in rows)} still running at the timeout, "
          f"{sum(r[1] == '-' for r in rows)} templates; refusals taking 1 s or more: {len(slow)}")
    for command, code, wall, said in slow:
        print(f"  {wall:.2f} s  exit {code}  {command}: {said}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
