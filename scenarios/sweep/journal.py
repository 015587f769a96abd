"""The sweep's journal (JSON lines, one record per finished point, fsynced) and its table (CSV, Parquet)."""

from __future__ import annotations

import csv
import importlib.util
import io
import json
import os
from pathlib import Path

from flexarm.provenance import jsonable, sha256_bytes, write_atomic

from ..metrics import METRICS
from .plan import Plan

#: Statuses a journal record can have; a rerun does not repeat DONE points (an ``error`` point runs again).
STATUSES = ("ok", "unbounded", "error")
DONE = ("ok", "unbounded")

#: The key of a line's seal: the SHA-256 of the line's record without it, as :func:`_canonical` writes it.
LINE_SEAL = "line_sha256"


def _canonical(record: dict) -> bytes:
    """The bytes a line's seal is taken over: sorted keys, no spaces; floats as Python writes them (exact round
    trip, NaN and infinities included), so reading a line and writing it again gives the same bytes."""
    return json.dumps(record, sort_keys=True, separators=(",", ":"), allow_nan=True).encode()


def seal_record(record: dict) -> dict:
    """``record`` as plain JSON values with its :data:`LINE_SEAL` added."""
    plain = json.loads(json.dumps({k: v for k, v in record.items() if k != LINE_SEAL}, default=jsonable,
                                  allow_nan=True))
    return {**plain, LINE_SEAL: sha256_bytes(_canonical(plain))}


class Journal:
    """Append-only JSON lines: one record per finished point, flushed and fsynced as it comes.

    Every line carries its own seal (:data:`LINE_SEAL`), so a number edited by hand is found when the journal is
    read: such a line, or one without a seal, is not used (:attr:`tampered` names it by its line number) and its
    point runs again (a sweep) or the journal is refused (an ILC run, whose trials build on each other).
    """

    def __init__(self, path: Path):
        self.path = Path(path)
        self.bad_lines = 0
        self.tampered: list[int] = []
        self._f = None

    def read(self) -> dict[str, dict]:
        """Latest sealed record per point key (lines that do not parse, e.g. cut by a crash, are skipped and
        counted in :attr:`bad_lines`; lines whose seal is missing or does not match are skipped and their
        1-based numbers listed in :attr:`tampered`). The records are returned without their seals."""
        records: dict[str, dict] = {}
        self.bad_lines = 0
        self.tampered = []
        if not self.path.is_file():
            return records
        for number, line in enumerate(self.path.read_text(errors="replace").splitlines(), 1):
            if not line.strip():
                continue
            try:
                rec = json.loads(line)
                key = rec["key"]
                seal = rec.pop(LINE_SEAL, None)
            except (json.JSONDecodeError, KeyError, TypeError, AttributeError):
                self.bad_lines += 1
                continue
            if seal != sha256_bytes(_canonical(rec)):
                self.tampered.append(number)
                continue
            records[key] = rec
        return records

    def problems(self) -> str:
        """What the last :meth:`read` skipped, as a sentence ('' when nothing)."""
        parts = []
        if self.tampered:
            shown = ", ".join(map(str, self.tampered[:10])) + (", ..." if len(self.tampered) > 10 else "")
            parts.append(f"{len(self.tampered)} line(s) whose seal ({LINE_SEAL}) is missing or does not match "
                         f"their content, edited or not written by this version (line {shown})")
        if self.bad_lines:
            parts.append(f"{self.bad_lines} unreadable line(s)")
        return f"{self.path}: skipped " + " and ".join(parts) if parts else ""

    def append(self, record: dict) -> None:
        if self._f is None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._f = open(self.path, "a+b")  # noqa: SIM115 - kept open for the sweep, closed by close()
            self._f.seek(0, os.SEEK_END)
            if self._f.tell() > 0:
                self._f.seek(-1, os.SEEK_END)
                if self._f.read(1) != b"\n":  # a line cut by a crash: never glue the next one to it
                    self._f.write(b"\n")
        self._f.write((json.dumps(seal_record(record), allow_nan=True) + "\n").encode())
        self._f.flush()
        os.fsync(self._f.fileno())

    def close(self) -> None:
        """Close the file; the handle is dropped even when closing fails (e.g. a full disk), then it raises."""
        f, self._f = self._f, None
        if f is not None:
            f.close()


def table_columns(plan: Plan) -> list[str]:
    insts = sorted(plan.sweep.scenario.fmus)
    return (["index", "key"] + [a.field for a in plan.sweep.axes] + ["status", *METRICS]
            + ["wall_time_s", "setup_time_s", "steps_done", "worker", "message", "commit", "finished_at"]
            + [f"fmu_sha256.{i}" for i in insts])


def table_rows(plan: Plan, records: dict[str, dict]) -> list[dict]:
    """One row per point the journal holds, in point order (the table's content)."""
    rows = []
    for p in plan.points:
        rec = records.get(p.key)
        if rec is None:
            continue
        row = {"index": p.index, "key": p.key, **p.values, "status": rec["status"]}
        metrics = rec.get("metrics") or {}
        row.update({m: metrics.get(m) for m in METRICS})
        for k in ("wall_time_s", "setup_time_s", "steps_done", "worker", "message", "commit", "finished_at"):
            row[k] = rec.get(k)
        row.update({f"fmu_sha256.{i}": s for i, s in (rec.get("fmu_sha256") or {}).items()})
        rows.append(row)
    return rows


def _cell(v) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v)
    return str(v)


def write_table(path: Path, columns: list[str], rows: list[dict]) -> list[Path]:
    """CSV (full float precision; empty cell = no value) and, when pyarrow is importable, Parquet."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(columns)
    for r in rows:
        w.writerow([_cell(r.get(c)) for c in columns])
    write_atomic(path, buf.getvalue())
    written = [path]
    if importlib.util.find_spec("pyarrow") is not None:
        import pyarrow as pa
        import pyarrow.parquet as pq

        data = {c: [r.get(c) for r in rows] for c in columns}
        out = io.BytesIO()
        pq.write_table(pa.table(data), out)
        write_atomic(path.with_suffix(".parquet"), out.getvalue())
        written.append(path.with_suffix(".parquet"))
    return written


def read_table(path: Path) -> list[dict[str, str]]:
    """The CSV table back as rows of strings."""
    with open(path, newline="") as f:
        return list(csv.DictReader(f))
