"""The scan log: every sample of a scan in one SQLite file, safe against crashes.

File format (SQLite 3, journal_mode=WAL, synchronous=FULL). One transaction per batch; a batch is one whole
pass (its `passes` row and all its `samples` rows) or one frame row. A crash, power loss or `kill -9` therefore
loses at most the batch that was being written; what is in the file is always whole passes. Format version
`arproj-scanlog/2` (meta key `format`); version 1 logs (no laser columns) are still read, their laser values
come back as NaN.

Coordinates: wall metres (x right, y up from the wall's lower-left corner, the `wall` frame) unless a name says
`drive_`: drive coordinates (u, v) are metres along the xy linear drives from the frame's origin (GRBL
machine position / 1000). A frame pose (x, y, phi) maps drive to wall coordinates:
    [x_wall, y_wall] = [x, y] + R(phi) @ [u, v],  R(phi) = [[cos, -sin], [sin, cos]], phi in radians.

Tables
  meta(key TEXT PRIMARY KEY, value TEXT)        values are JSON:
      format            "arproj-scanlog/2"
      created           ISO-8601 UTC time the log was created
      wall_fingerprint  sha256 of the wall content (scanner.wall.Wall.fingerprint); a scan never mixes walls
      wall_name, wall_path, wall_width_m, wall_height_m
      wall_json         the wall description itself (simulation only: the truth the simulator scanned;
                        absent/null for real hardware)
      plan              {"kind": "dense"|"adaptive", ...planner parameters}
      sensor            sensor configuration (sample rate, value scale, hysteresis_m, noise, ...)
      drives            drive configuration (travel_m, max speed, acceleration, scan speed)
      seed              integer seed of the simulation (null for real hardware)
      status            "running" or "complete"
  frames(frame_id INTEGER PRIMARY KEY, time_s REAL,           time_s: scan time the robot stood ready
         cmd_x_m, cmd_y_m, cmd_phi_rad,                       frame pose the planner commanded (cmd_y_m:
                                                              the lift's height of its band, 0 on a wall
                                                              within the drives' reach and in older logs)
         est_x_m, est_y_m, est_phi_rad, cov_json TEXT,        localization estimate and its 3x3 covariance
                                                              (row-major JSON, order x, y, phi; m², rad²)
         true_x_m, true_y_m, true_phi_rad,                    simulation truth (NULL on real hardware)
         laser_x_m, laser_x_sigma_m,                          the 2-D lasers' fix when the robot aligned
         laser_y_m, laser_y_sigma_m,                          (scanner.laser): frame pose x, y, φ against the
         laser_phi_rad, laser_phi_sigma_rad,                  side walls and floor, distance to and yaw
         laser_dist_m, laser_dist_sigma_m,                    against the scanned wall, each with its 1σ;
         laser_yaw_rad, laser_yaw_sigma_rad)                  NULL without a fix (format 2 only)
  passes(pass_id INTEGER PRIMARY KEY, frame_id, stage TEXT,   stage: raster | coarse | socket | confirm |
                                                              trace | stud | follow | point
         axis TEXT, direction INTEGER,                        axis 'x' (moves along drive u) or 'y' (along v);
                                                              direction +1 increasing, -1 decreasing coordinate
         start_u_m, start_v_m, end_u_m, end_v_m,              drive coordinates of the measuring move
         t_start_s, t_end_s, n_samples)
  samples(seq INTEGER PRIMARY KEY,                            unique, consecutive over the whole scan
          time_s REAL, frame_id INTEGER, pass_id INTEGER,     time_s: scan time in seconds (simulated
                                                              clock in simulation)
          drive_u_m, drive_v_m,                               drive position at the sample
          cmd_x_m, cmd_y_m,                                   commanded position on the wall (commanded
                                                              frame pose ∘ drive position)
          x_m, y_m,                                           measured position on the wall (localization
                                                              estimate ∘ drive position) — use these
          true_x_m, true_y_m,                                 simulation truth, NULL on real hardware
          axis INTEGER, direction INTEGER,                    axis 0 = x/u, 1 = y/v; direction ±1 of motion
          inductive REAL, capacitive REAL, ac REAL)           readings, display units 0..1 (device counts
                                                              / 1000), as in the paper's figures 5 and 6

One writer: a log open for writing (`create`, `open(writable=True)`) holds an exclusive flock on the sidecar
`LOG.lock` (the writer's pid and command line inside) until it is closed; a second writer is refused at once
with a LogInUseError naming that pid. The OS drops the lock when its process ends however it ends (kill -9
included), so it is never stale. Readers take no lock and keep working beside the writer (WAL). A new log is
built whole in `.LOG.creating` (schema and meta in one transaction) and renamed to LOG, so a kill leaves either
no log or a whole one; `overwrite` replaces only a file that is a scan log.

Reader API: `ScanLog.open(path)`; `.meta` (dict), `.samples()` -> dict of numpy arrays (one per column above,
float64 except seq/frame_id/pass_id/axis/direction int64; NULL -> NaN), `.frames()` -> dict of arrays with
`cov` (n, 3, 3), `.passes()` -> dict of arrays (stage/axis as numpy str arrays).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import sqlite3
import sys
from collections.abc import Mapping
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from geometry import provenance
from geometry.errors import InputError
from geometry.inputs import fail, float_array, is_number, parse_json, shown
from scanner.channels import NAMES as CHANNEL_NAMES
from scanner.laser import LASER_KEYS

FORMAT = "arproj-scanlog/2"
READABLE_FORMATS = frozenset({"arproj-scanlog/1", FORMAT})  # version 1: frames without the laser columns

SAMPLE_COLUMNS: tuple[str, ...] = (
    "seq", "time_s", "frame_id", "pass_id", "drive_u_m", "drive_v_m", "cmd_x_m", "cmd_y_m", "x_m", "y_m",
    "true_x_m", "true_y_m", "axis", "direction", *CHANNEL_NAMES,
)
INT_SAMPLE_COLUMNS = frozenset({"seq", "frame_id", "pass_id", "axis", "direction"})
FRAME_COLUMNS: tuple[str, ...] = (
    "frame_id", "time_s", "cmd_x_m", "cmd_y_m", "cmd_phi_rad", "est_x_m", "est_y_m", "est_phi_rad", "cov_json",
    "true_x_m", "true_y_m", "true_phi_rad", *LASER_KEYS,
)
PASS_COLUMNS: tuple[str, ...] = (
    "pass_id", "frame_id", "stage", "axis", "direction", "start_u_m", "start_v_m", "end_u_m", "end_v_m",
    "t_start_s", "t_end_s", "n_samples",
)

_SCHEMA = f"""
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS frames (frame_id INTEGER PRIMARY KEY, time_s REAL NOT NULL,
    cmd_x_m REAL NOT NULL, cmd_y_m REAL NOT NULL, cmd_phi_rad REAL NOT NULL,
    est_x_m REAL NOT NULL, est_y_m REAL NOT NULL, est_phi_rad REAL NOT NULL, cov_json TEXT NOT NULL,
    true_x_m REAL, true_y_m REAL, true_phi_rad REAL, {", ".join(k + " REAL" for k in LASER_KEYS)});
CREATE TABLE IF NOT EXISTS passes (pass_id INTEGER PRIMARY KEY, frame_id INTEGER NOT NULL, stage TEXT NOT NULL,
    axis TEXT NOT NULL, direction INTEGER NOT NULL, start_u_m REAL NOT NULL, start_v_m REAL NOT NULL,
    end_u_m REAL NOT NULL, end_v_m REAL NOT NULL, t_start_s REAL NOT NULL, t_end_s REAL NOT NULL,
    n_samples INTEGER NOT NULL);
CREATE TABLE IF NOT EXISTS samples ({", ".join(
    c + (" INTEGER PRIMARY KEY" if c == "seq" else " INTEGER NOT NULL" if c in INT_SAMPLE_COLUMNS else " REAL")
    for c in SAMPLE_COLUMNS)});
CREATE INDEX IF NOT EXISTS samples_by_pass ON samples(pass_id);
"""


REWRITE_HINT = "the log was changed by something other than arproj: scan again, or restore a copy"
MAX_META = 1000  # meta entries read; a log has about twenty
MAX_OUTSIDE_M = 5.0  # how far outside the wall a logged position may lie (a frame's localisation is off by cm)
MAX_DRIVE_M = 10.0   # drive travel, metres (the xy drives reach about 2 m)
MAX_READING = 10.0   # readings are display units 0..1; this far off is no reading
SQLITE_CORRUPT = 11  # SQLite's primary result code for a damaged database file


class DamagedLogError(InputError):
    """SQLite reports the log file as damaged (truncated or overwritten pages); ScanLog.open(salvage=True)
    reads what is left."""


class LogInUseError(InputError):
    """Another process holds the log open for writing."""


class WriterLock:
    """The one-writer lock of a log: an exclusive flock on the sidecar `LOG.lock`, which holds the writer's pid
    and command line. The OS releases it when the process ends, however it ends; release() removes the file."""

    def __init__(self, log_path: Path) -> None:
        self.log_path = log_path
        self.path = Path(f"{log_path}.lock")
        self._file: Any = None  # the open lock file while held (a file object, so that GC closes a forgotten one)

    def acquire(self) -> None:
        """Take the lock at once or raise LogInUseError naming its holder (never waits)."""
        while True:
            try:
                handle = open(self.path, "a+")  # noqa: SIM115 - held open while the lock is held
            except OSError as err:
                raise InputError(f"{self.log_path}: cannot create the writer lock {self.path} ({err.strerror})",
                                 "check that the log's folder is writable") from None
            try:
                fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                handle.seek(0)
                pid, _, command = handle.read(400).partition(" ")
                handle.close()
                holder = f"pid {pid.strip()}: {command.strip()}" if pid.strip().isdigit() else "pid unknown"
                raise LogInUseError(f"{self.log_path}: another scan is writing this log ({holder})",
                                    "wait for it to finish or stop it; two writers would mix two scans in one "
                                    "log (reading it, e.g. `arproj map`, works meanwhile)") from None
            try:  # the holder may have removed the file between our open and our flock: lock the new one
                same = os.fstat(handle.fileno()).st_ino == os.stat(self.path).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            handle.close()
        handle.truncate(0)
        handle.write(f"{os.getpid()} {' '.join(sys.argv)[:300]}\n")
        handle.flush()
        self._file = handle

    def probe(self) -> None:
        """Raise LogInUseError now if another process writes the log (a command checks this before its slow
        set-up; the lock is taken for real when the log is opened)."""
        if self.path.exists():
            self.acquire()
            self.release()

    def release(self) -> None:
        if self._file is None:
            return
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()  # while still locked: whoever opened it meanwhile retries on the new file
        self._file.close()
        self._file = None


class ScanLog:
    """A scan log file (see the module docstring for the format). Use `create` to write, `open` to read."""

    def __init__(self, path: Path, connection: sqlite3.Connection, writable: bool,
                 lock: WriterLock | None = None) -> None:
        self.path = path
        self._db = connection
        self.writable = writable
        self._lock = lock
        self.meta = self._read_meta()
        # columns the frames table really has (a version 1 log lacks the laser columns)
        present = {r[1] for r in self._rows("PRAGMA table_info(frames)")}
        self._frame_columns = tuple(c for c in FRAME_COLUMNS if c in present) if present else FRAME_COLUMNS

    # ------------------------------------------------------------------ opening
    @classmethod
    def create(cls, path: str | Path, meta: Mapping[str, Any], overwrite: bool = False) -> ScanLog:
        """Start a new log with the given meta entries (wall_fingerprint is required), whole or not at all.

        Refuses (InputError) a path that holds a file unless overwrite, a file that is not a scan log even with
        overwrite, and a log another process is writing (LogInUseError)."""
        path = Path(path)
        if "wall_fingerprint" not in meta:
            raise ValueError("meta needs wall_fingerprint")
        path.parent.mkdir(parents=True, exist_ok=True)
        lock = WriterLock(path)
        lock.acquire()
        try:
            if path.exists() or path.is_symlink():
                if not overwrite:
                    raise InputError(f"{path}: a scan log already exists here",
                                     "continue it with `arproj scan --resume LOG` or choose another --log path")
                _check_is_scan_log(path)
            entries = {"format": FORMAT, "created": datetime.now(UTC).isoformat(timespec="seconds"),
                       "made_by": provenance.record(), "status": "running", **meta}
            _build_whole(path, entries)
            return cls(path, _connect(path), writable=True, lock=lock)
        except BaseException:
            lock.release()
            raise

    @classmethod
    def open(cls, path: str | Path, writable: bool = False, salvage: bool = False) -> ScanLog:
        """Open an existing log (read-only unless writable). Raises InputError if it is not a scan log, and
        DamagedLogError (an InputError) if SQLite finds it damaged, e.g. truncated by a full disk or a copy cut
        short. salvage=True (read-only) opens such a file anyway, so that its sound pages can be read."""
        path = Path(path)
        if not path.is_file():
            if _creating_path(path).exists():
                raise InputError(f"{path}: scan log not found; a scan was stopped while creating it, before any "
                                 "pass was recorded", f"start it afresh with `arproj scan --log {path}`")
            raise InputError(f"{path}: scan log not found", "give the path passed to --log when scanning")
        lock = None
        if writable and not salvage:
            lock = WriterLock(path)
            lock.acquire()
        try:
            try:
                db = _connect(path, readonly=not writable or salvage, salvage=salvage)
                names = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type='table'")}
            except sqlite3.DatabaseError as err:
                if getattr(err, "sqlite_errorcode", None) == SQLITE_CORRUPT:
                    raise DamagedLogError(f"{path}: the scan log is damaged (SQLite says: {err})") from None
                raise InputError(f"{path}: not a scan log (SQLite says: {err})") from None
            if not {"meta", "frames", "passes", "samples"} <= names:
                db.close()
                raise InputError(f"{path}: not a scan log (tables meta/frames/passes/samples missing)")
            try:
                log = cls(path, db, writable, lock)
            except BaseException:
                db.close()
                raise
            if log.meta.get("format") not in READABLE_FORMATS:
                log.close()
                raise InputError(f"{path}: meta format = {log.meta.get('format')!r}, expected one of "
                                 f"{sorted(READABLE_FORMATS)}", "is it a scan log from a newer arproj? update arproj")
            return log
        except BaseException:
            if lock is not None:
                lock.release()
            raise

    def close(self) -> None:
        self._db.close()
        if self._lock is not None:
            self._lock.release()
            self._lock = None

    def __enter__(self) -> ScanLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _read_meta(self) -> dict[str, Any]:
        try:
            rows = self._db.execute("SELECT key, value FROM meta").fetchall()
        except sqlite3.OperationalError:
            return {}
        except sqlite3.DatabaseError as err:
            raise _database_error(self.path, err) from None
        meta = {}
        for key, value in rows[:MAX_META]:
            where = f"{self.path}: meta {shown(key)}"
            if not isinstance(key, str) or not isinstance(value, str):
                raise InputError(f"{where} = {shown(value)}: not a JSON text", REWRITE_HINT)
            meta[key] = parse_json(value, where, REWRITE_HINT, constants=True)  # json.dumps writes NaN
        return meta

    def _rows(self, query: str, params: list[Any] | tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
        """A query's rows; a damaged or foreign file is an InputError naming the log, not a traceback."""
        try:
            return self._db.execute(query, params).fetchall()
        except sqlite3.DatabaseError as err:
            raise _database_error(self.path, err) from None

    def _numbers(self, table: str, columns: tuple[str, ...], rows: list[tuple[Any, ...]]) -> np.ndarray:
        """rows as a float64 table (NULL -> NaN); text or blobs in a number column are refused, naming it."""
        try:  # NULL (None) becomes NaN
            return np.array(rows, dtype=np.float64).reshape(len(rows), len(columns))
        except (ValueError, TypeError, OverflowError):
            for r in rows:
                for c, v in zip(columns, r, strict=True):
                    if v is not None and not is_number(v):
                        raise fail(str(self.path), f"{table}.{c}", v, "must be a number", REWRITE_HINT) from None
            raise InputError(f"{self.path}: table {table} holds values that are not numbers", REWRITE_HINT) from None

    def _check_range(self, table: str, name: str, values: np.ndarray, lo: float, hi: float, what: str) -> None:
        bad = ~np.isnan(values) & ~((values >= lo) & (values <= hi))
        if bad.any():
            raise fail(str(self.path), f"{table}.{name}", float(values[np.argmax(bad)]), f"must be {what} "
                       f"({lo:g}..{hi:g})", REWRITE_HINT)

    def _wall_box(self) -> tuple[float, float, float, float]:
        """Where positions on the wall may lie: the wall (from meta) widened by MAX_OUTSIDE_M."""
        def size(key: str) -> float:
            value: Any = self.meta.get(key)
            return float(value) if is_number(value) and 0 < value < 1e3 else 1e3

        w, h = size("wall_width_m"), size("wall_height_m")
        return -MAX_OUTSIDE_M, -MAX_OUTSIDE_M, w + MAX_OUTSIDE_M, h + MAX_OUTSIDE_M

    # ------------------------------------------------------------------ checks
    def check_wall(self, fingerprint: str, wall_source: str = "") -> None:
        """Raise InputError unless the log was written for the wall with this fingerprint."""
        if self.meta.get("wall_fingerprint") != fingerprint:
            raise InputError(
                f"{self.path}: this log is from another wall (log: {self.meta.get('wall_name')!r} from "
                f"{self.meta.get('wall_path')!r}, fingerprint {str(self.meta.get('wall_fingerprint'))[:12]}; "
                f"given: {wall_source or 'wall'} fingerprint {fingerprint[:12]})",
                "resume with the wall the scan started on, or start a new log")

    # ------------------------------------------------------------------ writing (one transaction per batch)
    def set_meta(self, key: str, value: Any) -> None:
        with self._db:
            self._db.execute("INSERT OR REPLACE INTO meta(key, value) VALUES (?, ?)", (key, json.dumps(value)))
        self.meta[key] = value

    def append_frame(self, frame: Mapping[str, Any]) -> None:
        """Record a frame (keys as FRAME_COLUMNS; `cov` (3, 3) instead of cov_json)."""
        row = dict(frame)
        row["cov_json"] = json.dumps(np.asarray(row.pop("cov"), dtype=float).reshape(9).tolist())
        for key in ("true_x_m", "true_y_m", "true_phi_rad", *LASER_KEYS):
            value = row.get(key)
            row[key] = None if value is None or not np.isfinite(value) else float(value)
        cols = self._frame_columns
        with self._db:
            self._db.execute(f"INSERT INTO frames({', '.join(cols)}) VALUES ({', '.join('?' * len(cols))})",
                             [row[c] for c in cols])

    def append_pass(self, pass_row: Mapping[str, Any], samples: Mapping[str, np.ndarray]) -> None:
        """Record one whole pass and its samples in one transaction.

        samples : dict of (n,) arrays keyed by SAMPLE_COLUMNS except seq (assigned here, consecutive) and
            pass_id/frame_id (taken from pass_row); missing float columns are stored as NULL.
        """
        n = len(samples["time_s"])
        samples = {**samples, "pass_id": np.full(n, pass_row["pass_id"]),
                   "frame_id": np.full(n, pass_row["frame_id"])}
        start = self.next_seq()
        columns = [c for c in SAMPLE_COLUMNS if c != "seq"]
        arrays = []
        for c in columns:
            values = np.asarray(samples[c]) if c in samples else np.full(n, np.nan)
            if c in INT_SAMPLE_COLUMNS:
                arrays.append(values.astype(np.int64).tolist())
                continue
            values = values.astype(np.float64)
            nan = np.isnan(values)
            if nan.any():  # NULL in SQL
                arrays.append([None if missing else v for v, missing in zip(values.tolist(), nan, strict=True)])
            else:
                arrays.append(values.tolist())
        rows = zip(range(start, start + n), *arrays, strict=True)
        row = {**pass_row, "n_samples": n}
        with self._db:
            self._db.execute(f"INSERT INTO passes({', '.join(PASS_COLUMNS)}) VALUES "
                             f"({', '.join('?' * len(PASS_COLUMNS))})", [row[c] for c in PASS_COLUMNS])
            self._db.executemany(f"INSERT INTO samples({', '.join(SAMPLE_COLUMNS)}) VALUES "
                                 f"({', '.join('?' * len(SAMPLE_COLUMNS))})", rows)

    def next_seq(self) -> int:
        value = self._rows("SELECT MAX(seq) FROM samples")[0][0]
        return 0 if value is None else int(value) + 1

    # ------------------------------------------------------------------ reading
    def samples(self, pass_ids: list[int] | None = None) -> dict[str, np.ndarray]:
        """All samples (or those of some passes) ordered by seq, as a dict of (n,) arrays."""
        query = f"SELECT {', '.join(SAMPLE_COLUMNS)} FROM samples"
        params: list[int] = []
        if pass_ids is not None:
            query += f" WHERE pass_id IN ({', '.join('?' * len(pass_ids))})"
            params = [int(p) for p in pass_ids]
        rows = self._rows(query + " ORDER BY seq", params)
        table = self._numbers("samples", SAMPLE_COLUMNS, rows)
        out = {c: table[:, i] for i, c in enumerate(SAMPLE_COLUMNS)}
        x0, y0, x1, y1 = self._wall_box()
        for c in ("cmd_x_m", "x_m", "true_x_m"):
            self._check_range("samples", c, out[c], x0, x1, "on the wall, metres")
        for c in ("cmd_y_m", "y_m", "true_y_m"):
            self._check_range("samples", c, out[c], y0, y1, "on the wall, metres")
        for c in ("drive_u_m", "drive_v_m"):
            self._check_range("samples", c, out[c], -MAX_DRIVE_M, MAX_DRIVE_M, "a drive position, metres")
        for c in CHANNEL_NAMES:
            self._check_range("samples", c, out[c], -MAX_READING, MAX_READING, "a reading in display units")
        for c in INT_SAMPLE_COLUMNS:
            if np.isnan(out[c]).any() or (np.abs(out[c]) > 2**53).any():
                self._check_range("samples", c, np.where(np.isnan(out[c]), np.inf, out[c]), -2**53, 2**53,
                                  "an integer")
            out[c] = out[c].astype(np.int64)
        return out

    def frames(self) -> dict[str, np.ndarray]:
        """Frames ordered by id: arrays per FRAME_COLUMNS (cov_json replaced by cov (n, 3, 3))."""
        cols = self._frame_columns
        rows = self._rows(f"SELECT {', '.join(cols)} FROM frames ORDER BY frame_id")
        out: dict[str, np.ndarray] = {c: np.full(len(rows), np.nan) for c in FRAME_COLUMNS if c not in cols}
        k = cols.index("cov_json")
        numbers = tuple(c for c in cols if c != "cov_json")
        table = self._numbers("frames", numbers, [r[:k] + r[k + 1:] for r in rows])
        for i, c in enumerate(numbers):
            out[c] = table[:, i].astype(np.int64) if c == "frame_id" else table[:, i]
        covs = []
        for r in rows:
            where = f"{self.path}: frames.cov_json of frame {shown(r[0])}"
            if not isinstance(r[k], str):
                raise InputError(f"{where} = {shown(r[k])}: not a JSON text", REWRITE_HINT)
            covs.append(float_array(where, "cov_json", parse_json(r[k], where, REWRITE_HINT), (9,), hint=REWRITE_HINT))
        out["cov"] = np.array(covs, dtype=np.float64).reshape(-1, 3, 3)
        x0, y0, x1, y1 = self._wall_box()
        for prefix in ("cmd", "est", "true"):
            self._check_range("frames", f"{prefix}_x_m", out[f"{prefix}_x_m"], x0, x1, "on the wall, metres")
            self._check_range("frames", f"{prefix}_y_m", out[f"{prefix}_y_m"], y0, y1, "on the wall, metres")
        return out

    def passes(self) -> dict[str, np.ndarray]:
        rows = self._rows(f"SELECT {', '.join(PASS_COLUMNS)} FROM passes ORDER BY pass_id")
        out: dict[str, np.ndarray] = {}
        texts = ("stage", "axis")
        numbers = tuple(c for c in PASS_COLUMNS if c not in texts)
        table = self._numbers("passes", numbers, [tuple(v for c, v in zip(PASS_COLUMNS, r, strict=True)
                                                        if c not in texts) for r in rows])
        for i, c in enumerate(PASS_COLUMNS):
            if c in texts:
                values = [r[i] for r in rows]
                bad = [v for v in values if not isinstance(v, str) or len(v) > 32]
                if bad:
                    raise fail(str(self.path), f"passes.{c}", bad[0], "must be a short text", REWRITE_HINT)
                out[c] = np.array(values, dtype=str)
        for i, c in enumerate(numbers):
            if c in ("pass_id", "frame_id", "direction", "n_samples"):
                self._check_range("passes", c, np.where(np.isnan(table[:, i]), np.inf, table[:, i]), -2**53, 2**53,
                                  "an integer")
                out[c] = table[:, i].astype(np.int64)
            else:
                out[c] = table[:, i]
        return out

    def pass_count(self) -> int:
        return int(self._rows("SELECT COUNT(*) FROM passes")[0][0])

    def frame_ids(self) -> set[int]:
        return {int(r[0]) for r in self._rows("SELECT frame_id FROM frames")}


def _database_error(path: Path, err: sqlite3.DatabaseError) -> InputError:
    """What SQLite's error means for a person: a damaged log (salvage can read the rest) or no scan log."""
    if getattr(err, "sqlite_errorcode", None) == SQLITE_CORRUPT or "malformed" in str(err):
        return DamagedLogError(f"{path}: the scan log is damaged (SQLite says: {err})", REWRITE_HINT)
    return InputError(f"{path}: not a readable scan log (SQLite says: {err})", REWRITE_HINT)


def _creating_path(path: Path) -> Path:
    """Where a new log is built before it is renamed into place (a kill leaves it here, never at path)."""
    return path.with_name(f".{path.name}.creating")


def _check_is_scan_log(path: Path) -> None:
    """Raise InputError unless path is a scan log (sound or damaged) that `overwrite` may replace."""
    if not path.is_file():
        raise InputError(f"{path}: not a file; --overwrite replaces only a scan log", "choose another --log path")
    try:
        ScanLog.open(path).close()
    except DamagedLogError:
        return  # SQLite knows it as a database with damaged pages: a scan log cut short, replaceable
    except InputError as err:
        raise InputError(f"{err.message}; --overwrite replaces only a scan log, never another file",
                         "remove the file yourself if it may go, or choose another --log path") from None


def _build_whole(path: Path, entries: Mapping[str, Any]) -> None:
    """Write a new log with its schema and meta in one transaction beside path, then rename it onto path (the
    caller holds the writer lock). The old log's -wal/-shm go first: SQLite would replay them onto the new one."""
    tmp = _creating_path(path)
    for leftover in (tmp, Path(f"{tmp}-journal")):
        leftover.unlink(missing_ok=True)
    db = sqlite3.connect(str(tmp), isolation_level=None)
    try:
        db.execute("BEGIN")
        for statement in _SCHEMA.split(";"):
            if statement.strip():
                db.execute(statement)
        db.executemany("INSERT INTO meta(key, value) VALUES (?, ?)",
                       [(k, json.dumps(v)) for k, v in entries.items()])
        db.execute("COMMIT")
        db.execute("PRAGMA journal_mode=WAL")  # kept in the file's header
    finally:
        db.close()
    with open(tmp, "rb+") as handle:
        os.fsync(handle.fileno())
    for suffix in ("-wal", "-shm"):
        Path(f"{path}{suffix}").unlink(missing_ok=True)
    os.replace(tmp, path)
    directory = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(directory)
    finally:
        os.close(directory)


def _connect(path: Path, readonly: bool = False, salvage: bool = False) -> sqlite3.Connection:
    if readonly:
        db = sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=10.0)
        if salvage:
            # SQLite refuses a file shorter than its header's page count unless writable_schema is on; on a
            # read-only connection that only lets the pages that are there be read.
            db.execute("PRAGMA writable_schema=ON")
    else:
        db = sqlite3.connect(str(path), timeout=10.0)
        db.execute("PRAGMA journal_mode=WAL")
        db.execute("PRAGMA synchronous=FULL")  # a committed batch survives power loss, not just a crash
    return db
