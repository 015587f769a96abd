"""Command line: ``python -m scenarios list | run NAME|PATH|all [--case KEY] | sweep NAME|PATH | score CONTROLLER |
export-ssp NAME | results-page``.

Exit codes (docs/outcomes.md): 0 every case or point finished, ok, diverging, saturated or unbounded
(all results, the status says which); 1 some case or point ended with an FMU error (recorded as such; a crash,
exit or hang of an FMU in a process of its own too); 2 refused before anything ran (bad input, named field and
allowed values); 3 the results folder cannot be used or written (busy, permission, disk full); 4 results written,
standard output unwritable; 130 interrupted (Ctrl-C; nothing recorded as a result); 141 standard output's reader
left; 143 terminated (SIGTERM).
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import sys
from pathlib import Path

from scenarios.commands import (  # noqa: F401 - the exit codes: the command line's, imported from here
    EXIT_BROKEN_PIPE,
    EXIT_ERROR,
    EXIT_INTERRUPTED,
    EXIT_OK,
    EXIT_OUTPUT,
    EXIT_REFUSED,
    EXIT_STDOUT,
    EXIT_TERMINATED,
    StdoutUnwritable,
    dispatch,
    say_error,
)
from scenarios.config import MAX_CASES, MAX_SAMPLES, ScenarioError
from scenarios.master.cosim import CoSimulationError
from scenarios.master.fmu_proxy import DEFAULT_STEP_TIMEOUT_S, START_TIMEOUT_S
from scenarios.master.isolation import ISOLATE
from scenarios.run.fmus import DEFAULT_FMU_DIR, DEFAULT_NATIVE_FMU_DIR
from scenarios.run.outdir import OutputError, describe_os_error

#: Default results folder: relative to the current directory, so it works with any install.
DEFAULT_OUT = Path("results")


def _terminate(signum, frame):
    raise SystemExit(EXIT_TERMINATED)  # unwinds like Ctrl-C: temp files and unpacked FMUs are removed


def _reserve_stdio() -> None:
    """Closed standard streams (``>&-``, ``2>&-``) opened on /dev/null: so that no file we open later takes
    descriptor 0, 1 or 2 (an FMU's printf would write into it), and ``sys.stdout``/``sys.stderr`` are never None."""
    for fd in (0, 1, 2):
        try:
            os.fstat(fd)
        except OSError:
            null = os.open(os.devnull, os.O_RDWR)
            if null != fd:
                os.dup2(null, fd)
                os.close(null)
    for name, mode in (("stdin", "r"), ("stdout", "w"), ("stderr", "w")):
        if getattr(sys, name) is None:
            setattr(sys, name, open(os.devnull, mode))  # noqa: SIM115 - lives as long as the process


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m scenarios", description="Run the paper's experiments on our FMUs.",
                                 epilog="Exit codes: 0 ok, diverging, saturated or unbounded, 1 FMU error in a "
                                        "case, 2 refused input, 3 results folder unusable, 4 results written but "
                                        "standard output unwritable, 130 interrupted, 141 reader of standard output "
                                        "left, 143 terminated (see docs/outcomes.md).")
    sub = ap.add_subparsers(dest="command", required=True)
    sub.add_parser("list", help="list the shipped scenarios")
    run = sub.add_parser("run", help="run scenarios: shipped names (see list), all, or scenario files")
    run.add_argument("scenarios", nargs="+", help="shipped scenario names (python -m scenarios list), all, or files")
    run.add_argument("--out", type=Path, default=DEFAULT_OUT,
                     help="results folder, relative to the current directory (default: ./results); "
                          "a scenario writes OUT/<name>/, replacing an earlier run's folder when it completes")
    run.add_argument("--fmu-dir", type=Path, default=DEFAULT_FMU_DIR, help="where built FMUs live")
    _kind_options(run)
    run.add_argument("--controller", metavar="PATH_OR_NAME",
                     help="controller FMU to use instead of the scenario's: one of this project's FMU names or a "
                          ".fmu path (relative to the current directory); the scenario's controller parameters it "
                          "does not have are left out (printed), inputs named like the reference FMU's outputs are "
                          "fed by it (docs/own-controller.md)")
    run.add_argument("--set", dest="sets", action="append", default=[], metavar="INSTANCE.VARIABLE=VALUE",
                     help="set a parameter in every case, after the scenario's (e.g. controller.kp1=40, "
                          "plant.payload_mass=0.275; typed by the FMU's model description; repeatable)")
    run.add_argument("--case", dest="cases", action="append", default=[], metavar="KEY",
                     help="run only this case of each scenario (repeatable; default: all)")
    run.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    run.add_argument("--quiet", action="store_true", help="no progress bars")
    run.add_argument("--allow-large", action="store_true",
                     help=f"run past the caps of {MAX_SAMPLES} communication steps per case and {MAX_CASES} cases "
                          "per scenario (each case's record is kept in memory)")
    _isolation_options(run)
    sweep = sub.add_parser("sweep", help="run a sweep / Monte Carlo on Dask: a name in scenarios/sweeps/ or a file")
    sweep.add_argument("sweep", help="a sweep name in scenarios/sweeps/ (robustness, schedule) or a sweep file")
    sweep.add_argument("--out", type=Path, default=DEFAULT_OUT / "sweeps",
                       help="results folder, relative to the current directory (default: ./results/sweeps); "
                            "the sweep writes into OUT/<name>/ and resumes from its journal there")
    sweep.add_argument("--fmu-dir", type=Path, default=DEFAULT_FMU_DIR, help="where built FMUs live")
    _kind_options(sweep)
    sweep.add_argument("--scheduler", help="address of a running Dask scheduler, e.g. tcp://host:8786")
    sweep.add_argument("--workers", type=int, help="local cluster: worker processes (default: the cores)")
    sweep.add_argument("--serial", action="store_true", help="run in this process, no Dask (debugging)")
    sweep.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    sweep.add_argument("--quiet", action="store_true", help="no progress bar")
    sweep.add_argument("--allow-large", action="store_true",
                       help=f"run past the caps of {MAX_SAMPLES} samples per point and of the points per sweep "
                            "(each point's record is kept in memory)")
    _isolation_options(sweep)
    ssp = sub.add_parser("export-ssp", help="write a scenario's cases as SSP 1.0 packages (one .ssp per case)")
    ssp.add_argument("scenario", help="a shipped scenario (see: python -m scenarios list) or a path to a scenario file")
    ssp.add_argument("--out", type=Path, default=Path("build") / "ssp",
                     help="folder for <scenario>/<case>.ssp, relative to the current directory (default: ./build/ssp)")
    ssp.add_argument("--case", action="append", help="export only this case (repeatable; default: all)")
    ssp.add_argument("--fmu-dir", type=Path, default=DEFAULT_FMU_DIR, help="where built FMUs live")
    _kind_options(ssp)
    page = sub.add_parser("results-page", help="rewrite docs/results.md and the README's table from fresh runs")
    page.add_argument("--check", action="store_true",
                      help="do not write: exit 1 with a diff if the committed files differ from a fresh run")
    page.add_argument("--fmu-dir", type=Path, default=DEFAULT_FMU_DIR, help="where built FMUs live")
    from scenarios.score.cli import add_parser as add_score

    add_score(sub, DEFAULT_OUT, DEFAULT_FMU_DIR, _kind_options)
    sub.add_parser("conformance", add_help=False,
                   help="the conformance matrix: each case's one archive in every FMI master "
                        "(python -m scenarios conformance --help)")
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["conformance"]:  # its own command line (scenarios/reports/conformance_doc.py)
        from scenarios.reports.conformance_doc import main as conformance_main

        return conformance_main(argv[1:])
    _reserve_stdio()
    args = ap.parse_args(argv)
    previous = signal.signal(signal.SIGTERM, _terminate) if _main_thread() else None
    # A process started in the background by a non-interactive shell (`cmd &` in a script, CI) inherits SIGINT
    # ignored, and Python then installs no KeyboardInterrupt: a sweep waiting on Dask ran on through a Ctrl-C and
    # exited 0. A Ctrl-C (SIGINT) means the same here however the process was started.
    previous_int = signal.signal(signal.SIGINT, signal.default_int_handler) if _main_thread() else None
    try:
        return dispatch(args)
    except KeyboardInterrupt:
        say_error("interrupted: nothing of the interrupted run was recorded as a result")
        return EXIT_INTERRUPTED
    except (ScenarioError, CoSimulationError) as exc:
        say_error(f"error: {exc}")
        return EXIT_REFUSED
    except OutputError as exc:
        say_error(f"error: {exc}")
        return EXIT_OUTPUT
    except BrokenPipeError:  # the reader of our standard output went away (`... | head`): not a results error
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error at exit's flush
        say_error("stopped: standard output was closed (broken pipe)")
        return EXIT_BROKEN_PIPE
    except StdoutUnwritable as exc:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error at exit's flush
        where = ", ".join(str(w) for w in exc.written) or "(none)"
        say_error(f"error: standard output: cannot print the table ({exc}); the results were written: {where}")
        return EXIT_STDOUT
    except OSError as exc:
        say_error(f"error: cannot write results: {describe_os_error(exc)}")
        return EXIT_OUTPUT
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
        if previous_int is not None:
            signal.signal(signal.SIGINT, previous_int)


def _kind_options(parser) -> None:
    """--native / --python (override the scenario file's ``kind``) and the native FMUs' folder."""
    kind = parser.add_mutually_exclusive_group()
    kind.add_argument("--native", dest="kind", action="store_const", const="native",
                      help="use the native (plain C) FMUs, whatever the scenario's kind says")
    kind.add_argument("--python", dest="kind", action="store_const", const="python",
                      help="use the Python FMUs, whatever the scenario's kind says")
    parser.add_argument("--native-fmu-dir", type=Path, default=DEFAULT_NATIVE_FMU_DIR,
                        help="where built native FMUs live (their Python twins live in --fmu-dir)")


def _isolation_options(parser) -> None:
    """--isolate and --step-timeout: which FMUs run in a process of their own, and how long a call may take."""
    parser.add_argument("--isolate", choices=ISOLATE, default="foreign",
                        help="run these FMUs each in a process of their own, where a crash, a hang or an exit ends "
                             "only its case (as error): foreign (default: those given as a .fmu path) or all; the "
                             "others run in this process, at full speed")
    parser.add_argument("--step-timeout", type=_seconds, default=DEFAULT_STEP_TIMEOUT_S, metavar="SECONDS",
                        help="the longest one communication step of an FMU in its own process may take before the "
                             f"process is killed and the case ends as error (default {DEFAULT_STEP_TIMEOUT_S:g} s; "
                             f"loading, initialising and a run's first step get at least {START_TIMEOUT_S:g} s)")


def _seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (value > 0 and math.isfinite(value)):
        raise argparse.ArgumentTypeError(f"a number of seconds > 0, got {text!r}")
    return value


def _main_thread() -> bool:
    import threading

    return threading.current_thread() is threading.main_thread()


if __name__ == "__main__":
    sys.exit(main())
