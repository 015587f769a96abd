"""The committed baseline file: our controllers through the same battery (``python -m scenarios score
--write-baseline`` rewrites it; ``tests/test_score.py`` holds it and the battery together)."""

from __future__ import annotations

import json
from pathlib import Path

from flexarm.provenance import git_commit, write_json

from . import battery

#: The baselines of the page: every controller of :data:`battery.BASELINES` through the battery, native FMUs.
BASELINE_FILE = Path(__file__).resolve().parent / "baseline.json"
#: What the file keeps of a case's record (no series).
KEPT = ("status", "verdict", "growth_rate_per_s", "onset_s", "saturated_share", "metrics", "settle_s", "message")


class BaselineError(Exception):
    """The baseline file is missing or was made with another battery."""


def summary(result: dict) -> dict:
    """A battery result (:func:`scenarios.score.run.run_battery`) as the baseline file keeps it."""
    return {key: {k: rec.get(k) for k in KEPT} for key, rec in result["cases"].items()}


def write(results: dict[str, dict], kind: str, path: Path = BASELINE_FILE) -> Path:
    """Write the baseline file from {controller name: battery result}."""
    write_json(path, {"battery_version": battery.BATTERY_VERSION, "battery_sha256": battery.battery_sha256(),
                      "kind": kind, "commit": git_commit(),
                      "controllers": {name: summary(r) for name, r in results.items()},
                      "regenerate": "python -m scenarios score --write-baseline"})
    return path


def load(path: Path = BASELINE_FILE) -> dict:
    """The baseline file, refused (BaselineError) when it was made with another battery than this one."""
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise BaselineError(f"{path}: {exc} (regenerate: python -m scenarios score --write-baseline)") from exc
    if doc.get("battery_sha256") != battery.battery_sha256():
        raise BaselineError(f"{path}: made with battery {doc.get('battery_version')} "
                            f"({str(doc.get('battery_sha256'))[:12]}), this is battery {battery.BATTERY_VERSION} "
                            f"({battery.battery_sha256()[:12]}): regenerate it with python -m scenarios score "
                            "--write-baseline")
    return doc
