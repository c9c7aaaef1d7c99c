"""The results of a sweep: an append-only journal and the tables made from it.

``results.jsonl`` is the source of truth: one JSON line per finished run (ok or failed),
written to the file (handed to the operating system) the moment the run completes, so an
interrupted or killed sweep loses nothing it finished. Making it durable against a crash of
the machine itself (``fsync``) is up to the caller: :meth:`ResultsStore.append` syncs by
default, and the sweep runner syncs once per burst of records (group commit, see
:mod:`conformal_control.experiments.runner`).

``results.csv`` (and ``results.parquet`` when pyarrow is installed) are one flat row per
run key (the latest record of each key), rewritten from the journal through a uniquely
named temporary file and an atomic rename.

A journal line that cannot be read (torn by a crash or a full disk, not UTF-8, valid JSON
that is not a run record: see :func:`record_problem`) is skipped, counted and reported once
with its line number; it is never rewritten or deleted. Before appending, the store makes
sure the journal ends with a newline, so a torn tail stays a line of its own instead of
swallowing the next record.

Run directories are recorded relative to the sweep folder (``runs/<name>``), so a sweep
folder can be moved or copied. Journals written with absolute paths are read too: such a
path is trusted only if it exists inside the folder, otherwise ``<folder>/runs/<name>``
is used.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import math
import os
import re
import warnings
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from ..core.fileio import TMP_PREFIX as _TMP_PREFIX
from ..core.fileio import TMP_SUFFIX as _TMP_SUFFIX
from ..core.fileio import atomic_write
from .plan import settings_view

__all__ = ["JournalWarning", "ResultsStore", "atomic_write", "flatten_record", "record_problem"]

_FIRST = ["key", "status", "label", "scene", "predictor", "learn", "seed", "max_frames"]
#: Names temporary files had before they were unique (removed when the folder is locked).
_OLD_TMP = ("results.csv.tmp", "results.parquet.tmp")


#: a run directory as a sweep records it: ``runs/<name>`` (no ``..``, no separator)
_PLAIN_RUN_DIR = re.compile(r"runs/(?!\.\.?$)[^/\\]+")


class JournalWarning(UserWarning):
    """Some lines of ``results.jsonl`` could not be read and were skipped."""


def _scalar(v: Any) -> Any:
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, (dict, list, tuple)):
        return json.dumps(v, sort_keys=True)
    return v


#: Optional fields of a run record and the JSON types they may hold.
_RECORD_FIELDS: dict[str, tuple[type, ...]] = {
    "run_dir": (str, type(None)),
    "metrics": (dict, type(None)),
    "config": (dict, type(None)),
    "error": (str, type(None)),
    "traceback": (str, type(None)),
    "worker": (str, type(None)),
    "elapsed_s": (int, float, type(None)),
    "finished_at": (int, float, type(None)),
}
#: Parts of ``config`` that must be mappings when present (``spec``: a run written by
#: :meth:`~conformal_control.experiments.plan.SweepRun.as_dict`; the others: by 0.3).
_CONFIG_MAPPINGS = ("meta", "spec", "episode", "predictor_params", "params")


def record_problem(rec: Any) -> str | None:
    """Why ``rec`` (a parsed journal line) is not a run record, or None if it is one.

    A run record is an object with a string ``key``, a ``status`` of ``"ok"`` or
    ``"failed"`` and, when present, fields of the types :func:`execute_run` writes
    (``metrics`` and ``config`` objects, ``run_dir`` a string or null, ...). A line of
    valid JSON that fails this is skipped and reported like a torn line.
    """
    if not isinstance(rec, dict):
        return f"a JSON {type(rec).__name__}, not an object"
    if not isinstance(rec.get("key"), str) or not rec["key"]:
        return "no string 'key'"
    if rec.get("status") not in ("ok", "failed"):
        return f"status {rec.get('status')!r} is neither 'ok' nor 'failed'"
    for name, types in _RECORD_FIELDS.items():
        if name in rec and (not isinstance(rec[name], types) or isinstance(rec[name], bool)):
            return f"{name!r} is a {type(rec[name]).__name__}"
    cfg = rec.get("config") or {}
    for name in _CONFIG_MAPPINGS:
        if cfg.get(name) is not None and not isinstance(cfg[name], dict):
            return f"'config.{name}' is a {type(cfg[name]).__name__}"
    params = (cfg.get("spec") or {}).get("params")
    if params is not None and not isinstance(params, dict):
        return f"'config.spec.params' is a {type(params).__name__}"
    return None


def flatten_record(rec: dict[str, Any]) -> dict[str, Any]:
    """One flat row: run identity, parameters (``param.*``), metrics, status, error.

    The columns are those of 0.3 (:func:`~conformal_control.experiments.plan.settings_view`
    of the stored run), whichever version wrote the record.

    Parameters
    ----------
    rec : dict
        A journal record.
    """
    cfg = settings_view(rec.get("config") or {})
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
    for k, v in (cfg.get("meta") or {}).items():
        row[str(k)] = _scalar(v)
    for k, v in sorted((cfg.get("episode") or {}).items()):
        row[f"episode.{k}"] = _scalar(v)
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

    Attributes
    ----------
    bad_lines_ : list of (int, str)
        Line numbers (1-based) of the journal lines the last read skipped, with the reason.
    """

    def __init__(self, out_dir: str | os.PathLike[str]) -> None:
        self.out_dir = Path(out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.journal = self.out_dir / "results.jsonl"
        self.csv_path = self.out_dir / "results.csv"
        self.parquet_path = self.out_dir / "results.parquet"
        self.bad_lines_: list[tuple[int, str]] = []
        self._warned: set[tuple[int, str]] = set()
        # the journal as last read: (size, mtime_ns), its records, the number of its lines
        self._cache: tuple[tuple[int, int], list[dict[str, Any]], int] | None = None
        # lines this store appended since, not parsed yet: bytes, which the garbage collector
        # does not track (parsed records would make its full collections, whose cost grows
        # with the objects alive, ever longer during a sweep)
        self._unparsed: list[bytes] = []
        # flat row of a cached record, by id() (the cache holds the records alive)
        self._flat: dict[int, dict[str, Any]] = {}

    # ------------------------------------------------------------------ journal
    def records(self) -> list[dict[str, Any]]:
        """Every readable record of the journal, in order.

        Unreadable lines (torn, not UTF-8, not a JSON run record) are skipped and listed
        in :attr:`bad_lines_`; the first time a line is skipped a :class:`JournalWarning`
        names it. The file is never modified here.
        """
        try:
            st = self.journal.stat()
        except FileNotFoundError:
            self.bad_lines_ = []
            return []
        stamp = (st.st_size, st.st_mtime_ns)
        if self._cache is not None and self._cache[0] == stamp:
            _, out, n_lines = self._cache
            if self._unparsed:  # the lines appended since: line numbers n_lines + 1, ...
                bad = self._parse(self._unparsed, n_lines + 1, out)
                self._cache = (stamp, out, n_lines + len(self._unparsed))
                self._unparsed = []
                if bad:
                    self.bad_lines_ = self.bad_lines_ + bad
                    self._warn(bad)
            return list(out)
        data = self.journal.read_bytes()
        lines = data.split(b"\n")
        out = []
        bad = self._parse(lines, 1, out)
        self.bad_lines_ = bad
        self._warn(bad)
        self._cache = (stamp, out, data.count(b"\n"))
        self._unparsed = []
        self._flat = {}
        return list(out)

    @staticmethod
    def _parse(lines: list[bytes], first: int, out: list[dict[str, Any]]) -> list[tuple[int, str]]:
        """Append the run records of ``lines`` (numbered from ``first``) to ``out``; return
        the unreadable ones as (line number, reason)."""
        bad: list[tuple[int, str]] = []
        for n, raw in enumerate(lines, start=first):
            if not raw.strip():
                continue
            try:
                text = raw.decode("utf-8")
            except UnicodeDecodeError:
                bad.append((n, "not UTF-8"))
                continue
            try:
                rec = json.loads(text)
            except json.JSONDecodeError:
                bad.append((n, "torn or not JSON"))
                continue
            except RecursionError:
                bad.append((n, "nested too deeply"))
                continue
            why = record_problem(rec)
            if why is not None:
                bad.append((n, f"not a run record: {why}"))
                continue
            out.append(rec)
        return bad

    def _warn(self, bad: list[tuple[int, str]]) -> None:
        new = [b for b in bad if b not in self._warned]
        if new:
            self._warned.update(new)
            warnings.warn(JournalWarning(self.describe_bad_lines(new)), stacklevel=3)

    def describe_bad_lines(self, bad: list[tuple[int, str]] | None = None) -> str:
        """One sentence naming the skipped journal lines (all, or ``bad``)."""
        bad = self.bad_lines_ if bad is None else bad
        if not bad:
            return f"{self.journal}: every line is readable"
        shown = ", ".join(f"{n} ({why})" for n, why in bad[:5])
        more = f" and {len(bad) - 5} more" if len(bad) > 5 else ""
        s = "" if len(bad) == 1 else "s"
        return (
            f"{self.journal}: skipped {len(bad)} unreadable line{s}: line{s} {shown}{more}; "
            "the file is left as it is and the runs of those lines, if any, are redone"
        )

    def latest(self) -> dict[str, dict[str, Any]]:
        """The last record of every key."""
        return {r["key"]: r for r in self.records()}

    def interrupted_summary(self) -> str:
        """What an interrupted sweep left in this folder, read back from its journal (only
        true statements): the runs finished and failed, those recovered from their run
        directories, and how to resume."""
        latest = self.latest()
        ok = sum(r.get("status") == "ok" for r in latest.values())
        failed = len(latest) - ok
        recovered = sum(bool(r.get("recovered")) for r in latest.values())
        adopted = f" ({recovered} recovered from their run directories)" if recovered else ""
        return (
            f"{ok} finished and {failed} failed run(s) are in the journal {self.journal}"
            f"{adopted}; the runs in flight were abandoned; run the same command again to "
            "resume"
        )

    def run_path(self, run_dir: str | os.PathLike[str] | None) -> Path | None:
        """Where a recorded run directory is now, inside this sweep folder.

        A relative path is taken relative to the folder. An absolute path (journals of
        earlier versions) is used only if it exists inside the folder; otherwise (a copied
        or moved folder) the directory of the same name under ``<folder>/runs`` is used.
        """
        if not run_dir:
            return None
        p = Path(run_dir)
        if not p.is_absolute():
            return self.out_dir / p
        with contextlib.suppress(ValueError, OSError):
            p.resolve().relative_to(self.out_dir.resolve())
            if p.exists():
                return p
        return self.out_dir / "runs" / p.name

    def relative_run_dir(self, run_dir: str | os.PathLike[str] | None) -> str | None:
        """A run directory as recorded: relative to the folder, with ``/`` separators."""
        if isinstance(run_dir, str) and _PLAIN_RUN_DIR.fullmatch(run_dir):
            return run_dir  # "runs/<name>", what every sweep records: nothing to resolve
        p = self.run_path(run_dir)
        if p is None:
            return None
        try:
            return p.resolve().relative_to(self.out_dir.resolve()).as_posix()
        except (ValueError, OSError):
            return f"runs/{p.name}"

    def finished(self, *, include_failed: bool = False) -> set[str]:
        """Keys whose run finished (ok, or also failed with ``include_failed``).

        A run counts as finished only if its run directory still holds ``metrics.json``
        (ok runs) - deleting a run directory makes a resumed sweep redo it.
        """
        keys = set()
        for key, r in self.latest().items():
            if r.get("status") == "ok":
                rd = self.run_path(r.get("run_dir"))
                if rd is not None and (rd / "metrics.json").exists():
                    keys.add(key)
            elif include_failed:
                keys.add(key)
        return keys

    def append(self, record: dict[str, Any], *, sync: bool = True) -> None:
        """Append one record and, with ``sync`` (default), fsync it.

        The line reaches the operating system before this returns either way (it survives
        the end of this process); ``sync=False`` leaves making it durable against a crash
        of the machine to a later :meth:`sync` (which covers every line written before it).
        If the journal does not end with a newline (a line torn by a crash), one is
        written first, so the torn fragment stays a (skipped) line of its own.
        """
        line = (json.dumps(record, default=_json_default) + "\n").encode()
        with self.journal.open("ab+") as fh:
            before = os.fstat(fh.fileno())
            end = fh.seek(0, os.SEEK_END)
            torn = False
            if end > 0:
                fh.seek(end - 1)
                if fh.read(1) != b"\n":
                    line = b"\n" + line
                    torn = True
            fh.write(line)
            fh.flush()
            if sync:
                os.fsync(fh.fileno())
            after = os.fstat(fh.fileno())
        # keep the parsed journal current without reading it again (a sweep of thousands
        # of runs would otherwise re-parse it after every run): only if the cache held
        # the file exactly as it was before this line
        cache = self._cache
        if cache is None and before.st_size == 0:  # a new journal: nothing to read back
            cache = ((0, before.st_mtime_ns), [], 0)
            self._unparsed = []
            self.bad_lines_ = []
        if (
            cache is not None
            and not torn
            and cache[0] == (before.st_size, before.st_mtime_ns)
            and after.st_size == before.st_size + len(line)
        ):
            # parsed when the records are next asked for: JSON types, not the caller's
            self._unparsed.append(line[:-1])
            self._cache = ((after.st_size, after.st_mtime_ns), cache[1], cache[2])
        else:
            self._cache = None
            self._unparsed = []

    def sync(self) -> None:
        """Make every line appended so far durable (``fsync`` the journal), if it exists."""
        try:
            fd = os.open(self.journal, os.O_WRONLY | os.O_APPEND)
        except FileNotFoundError:
            return
        try:
            os.fsync(fd)
        finally:
            os.close(fd)

    # ------------------------------------------------------------------ tables
    def rows(
        self, keys: Iterable[str] | None = None, *, absolute: bool = False
    ) -> list[dict[str, Any]]:
        """Flat rows of the latest record of each key (all keys, or ``keys`` in order).

        ``run_dir`` is relative to the sweep folder, or absolute with ``absolute=True``.
        """
        latest = self.latest()
        order = list(keys) if keys is not None else list(latest)
        out: list[dict[str, Any]] = []
        runs: str | None = None  # <folder>/runs resolved once (a plain run_dir's parent)
        for k in order:
            rec = latest.get(k)
            if rec is None:
                continue
            flat = self._flat.get(id(rec))
            if flat is None:
                flat = self._flat[id(rec)] = flatten_record(rec)
            row = dict(flat)
            rd = row["run_dir"]
            if rd and absolute and isinstance(rd, str) and _PLAIN_RUN_DIR.fullmatch(rd):
                # "runs/<name>" (what every sweep records): resolving the folder once and
                # checking the name alone gives what resolving the whole path would
                if runs is None:
                    runs = str((self.out_dir / "runs").resolve())
                name = os.path.join(runs, rd[5:])
                row["run_dir"] = os.path.realpath(name) if os.path.islink(name) else name
            elif rd and absolute:
                path = self.run_path(rd)
                assert path is not None  # run_path only gives None for an empty run_dir
                row["run_dir"] = str(path.resolve())
            elif rd:
                row["run_dir"] = self.relative_run_dir(rd)
            out.append(row)
        return out

    def write_tables(self, *, parquet: bool = True) -> list[Path]:
        """Rewrite ``results.csv`` (and ``results.parquet`` if pyarrow is available).

        ``parquet=False`` writes the CSV only and deletes a ``results.parquet`` an earlier
        sweep left here, which would otherwise no longer match the journal.
        """
        rows = self.rows()
        cols: list[str] = []
        for c in _FIRST:
            cols.append(c)
        for r in rows:
            for c in r:
                if c not in cols:
                    cols.append(c)
        buf = io.StringIO(newline="")
        w = csv.DictWriter(buf, fieldnames=cols)
        w.writeheader()
        for r in rows:
            w.writerow({c: "" if r.get(c) is None else r.get(c) for c in cols})
        atomic_write(self.csv_path, lambda tmp: tmp.write_text(buf.getvalue(), newline=""))
        written = [self.csv_path]
        if not parquet:
            self.parquet_path.unlink(missing_ok=True)
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
            atomic_write(self.parquet_path, lambda tmp: pq.write_table(table, tmp))
            written.append(self.parquet_path)
        return written

    def remove_stale_temp_files(self) -> list[Path]:
        """Delete temporary files a killed writer left (call only while holding the lock)."""
        gone = []
        for p in self.out_dir.iterdir():
            name = p.name
            stale = name in _OLD_TMP or (
                name.startswith(_TMP_PREFIX)
                and name.endswith(_TMP_SUFFIX)
                and name[1:].split(".", 1)[0] in ("results", "sweep", "summary")
            )
            if stale and p.is_file():
                with contextlib.suppress(FileNotFoundError):
                    p.unlink()
                    gone.append(p)
        return gone


def _json_default(obj: Any) -> Any:
    if hasattr(obj, "item"):
        return obj.item()
    return repr(obj)
