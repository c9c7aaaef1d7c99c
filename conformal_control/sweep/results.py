"""The results of a sweep: an append-only journal and the tables made from it.

``results.jsonl`` is the source of truth: one JSON line per finished run (ok or failed),
appended and flushed the moment the run completes, so an interrupted sweep loses nothing
it finished. ``results.csv`` (and ``results.parquet`` when pyarrow is installed) are one
flat row per run key (the latest record of each key), rewritten from the journal.
"""

from __future__ import annotations

import csv
import json
import math
import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any

__all__ = ["ResultsStore", "flatten_record"]

_FIRST = ["key", "status", "label", "scene", "predictor", "learn", "seed", "max_frames"]


def _scalar(v: Any) -> Any:
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, (dict, list, tuple)):
        return json.dumps(v, sort_keys=True)
    return v


def flatten_record(rec: dict[str, Any]) -> dict[str, Any]:
    """One flat row: run identity, parameters (``param.*``), metrics, status, error."""
    cfg = rec.get("config") or {}
    row: dict[str, Any] = {
        "key": rec.get("key"),
        "status": rec.get("status"),
        "label": cfg.get("label", ""),
        "scene": cfg.get("scene"),
        "predictor": cfg.get("predictor"),
        "learn": cfg.get("learn"),
        "seed": cfg.get("seed"),
        "max_frames": cfg.get("frames"),
    }
    for k, v in sorted((cfg.get("predictor_params") or {}).items()):
        row[f"predictor_params.{k}"] = _scalar(v)
    for k, v in sorted((cfg.get("params") or {}).items()):
        row[f"param.{k}"] = _scalar(v)
    for k, v in (rec.get("metrics") or {}).items():
        row[k] = _scalar(v)
    row["elapsed_s"] = rec.get("elapsed_s")
    row["worker"] = rec.get("worker")
    row["run_dir"] = rec.get("run_dir")
    row["error"] = rec.get("error")
    return row


class ResultsStore:
    """Journal + tables of one sweep folder.

    Parameters
    ----------
    out_dir : path
        The sweep's folder (created if needed).
    """

    def __init__(self, out_dir: str | os.PathLike[str]) -> None:
        self.out_dir = Path(out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.journal = self.out_dir / "results.jsonl"
        self.csv_path = self.out_dir / "results.csv"
        self.parquet_path = self.out_dir / "results.parquet"

    # ------------------------------------------------------------------ journal
    def records(self) -> list[dict[str, Any]]:
        """Every record in the journal (a torn last line from a crash is ignored)."""
        if not self.journal.exists():
            return []
        out = []
        with self.journal.open() as fh:
            for line in fh:
                line = line.strip()
                if not line:
                    continue
                try:
                    out.append(json.loads(line))
                except json.JSONDecodeError:
                    continue
        return out

    def latest(self) -> dict[str, dict[str, Any]]:
        """The last record of every key."""
        return {r["key"]: r for r in self.records() if "key" in r}

    def finished(self, *, include_failed: bool = False) -> set[str]:
        """Keys whose run finished (ok, or also failed with ``include_failed``).

        A run counts as finished only if its run directory still holds ``metrics.json``
        (ok runs) - deleting a run directory makes a resumed sweep redo it.
        """
        keys = set()
        for key, r in self.latest().items():
            if r.get("status") == "ok":
                rd = r.get("run_dir")
                if rd and (Path(rd) / "metrics.json").exists():
                    keys.add(key)
            elif include_failed:
                keys.add(key)
        return keys

    def append(self, record: dict[str, Any]) -> None:
        """Append one record and flush it to disk."""
        with self.journal.open("a") as fh:
            fh.write(json.dumps(record, default=_json_default) + "\n")
            fh.flush()
            os.fsync(fh.fileno())

    # ------------------------------------------------------------------ tables
    def rows(self, keys: Iterable[str] | None = None) -> list[dict[str, Any]]:
        """Flat rows of the latest record of each key (all keys, or ``keys`` in order)."""
        latest = self.latest()
        order = list(keys) if keys is not None else list(latest)
        return [flatten_record(latest[k]) for k in order if k in latest]

    def write_tables(self, *, parquet: bool = True) -> list[Path]:
        """Rewrite ``results.csv`` (and ``results.parquet`` if pyarrow is available)."""
        rows = self.rows()
        cols: list[str] = []
        for c in _FIRST:
            cols.append(c)
        for r in rows:
            for c in r:
                if c not in cols:
                    cols.append(c)
        tmp = self.csv_path.with_suffix(".csv.tmp")
        with tmp.open("w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=cols)
            w.writeheader()
            for r in rows:
                w.writerow({c: "" if r.get(c) is None else r.get(c) for c in cols})
        tmp.replace(self.csv_path)
        written = [self.csv_path]
        if parquet and rows:
            try:
                import pyarrow as pa
                import pyarrow.parquet as pq
            except ImportError:
                return written
            arrays = []
            for c in cols:
                values = [r.get(c) for r in rows]
                try:
                    arrays.append(pa.array(values))
                except (pa.ArrowInvalid, pa.ArrowTypeError):  # mixed types: keep as text
                    arrays.append(pa.array([None if v is None else str(v) for v in values]))
            table = pa.Table.from_arrays(arrays, names=cols)
            tmp = self.parquet_path.with_suffix(".parquet.tmp")
            pq.write_table(table, tmp)
            tmp.replace(self.parquet_path)
            written.append(self.parquet_path)
        return written


def _json_default(obj: Any) -> Any:
    if hasattr(obj, "item"):
        return obj.item()
    return repr(obj)
