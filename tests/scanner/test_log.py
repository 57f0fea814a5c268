"""The SQLite scan log: round trip, batches, refusal of a log from another wall."""

import sqlite3

import numpy as np
import pytest

from geometry.errors import InputError
from scanner.log import SAMPLE_COLUMNS, ScanLog


def _samples(n, offset=0.0):
    rng = np.random.default_rng(n)
    cols = {c: rng.random(n) + offset for c in SAMPLE_COLUMNS if c not in ("seq", "axis", "direction",
                                                                           "frame_id", "pass_id")}
    cols.update(frame_id=np.zeros(n, int), pass_id=np.zeros(n, int), axis=np.zeros(n, int),
                direction=np.ones(n, int))
    cols["true_x_m"] = np.full(n, np.nan)
    return cols


def _pass(pass_id):
    return {"pass_id": pass_id, "frame_id": 0, "stage": "raster", "axis": "x", "direction": 1,
            "start_u_m": 0.0, "start_v_m": 0.1, "end_u_m": 0.3, "end_v_m": 0.1, "t_start_s": 1.0, "t_end_s": 7.0}


def test_round_trip_of_frames_passes_and_samples(tmp_path):
    log = ScanLog.create(tmp_path / "scan.db", {"wall_fingerprint": "abc", "wall_name": "w", "plan": {"kind": "dense"}})
    cov = np.diag([1e-5, 2e-5, 1e-6])
    log.append_frame({"frame_id": 0, "time_s": 0.0, "cmd_x_m": 0.0, "cmd_y_m": 0.0, "cmd_phi_rad": 0.0,
                      "est_x_m": 0.001, "est_y_m": -0.002, "est_phi_rad": 0.0005, "cov": cov})
    first, second = _samples(50), _samples(30, offset=1.0)
    log.append_pass(_pass(0), first)
    log.append_pass({**_pass(1), "direction": -1}, second)
    log.close()
    with ScanLog.open(tmp_path / "scan.db") as back:
        assert back.meta["plan"] == {"kind": "dense"} and back.meta["status"] == "running"
        s = back.samples()
        np.testing.assert_array_equal(s["seq"], np.arange(80))
        np.testing.assert_allclose(s["inductive"], np.concatenate([first["inductive"], second["inductive"]]))
        assert np.isnan(s["true_x_m"]).all()
        assert s["seq"].dtype == np.int64
        f = back.frames()
        np.testing.assert_allclose(f["cov"][0], cov)
        assert np.isnan(f["true_x_m"][0])
        p = back.passes()
        assert p["n_samples"].tolist() == [50, 30] and p["direction"].tolist() == [1, -1]
        assert p["stage"].tolist() == ["raster", "raster"]
        assert len(back.samples(pass_ids=[1])["seq"]) == 30


def test_a_failed_batch_leaves_no_partial_pass(tmp_path):
    log = ScanLog.create(tmp_path / "scan.db", {"wall_fingerprint": "abc"})
    log.append_pass(_pass(0), _samples(10))
    with pytest.raises(sqlite3.IntegrityError):
        log.append_pass(_pass(0), _samples(10))  # duplicate pass id: the whole batch is rolled back
    assert log.pass_count() == 1 and log.next_seq() == 10


def test_log_from_another_wall_and_not_a_log(tmp_path):
    log = ScanLog.create(tmp_path / "scan.db", {"wall_fingerprint": "abc", "wall_name": "kitchen",
                                                "wall_path": "kitchen.yaml"})
    log.check_wall("abc")
    with pytest.raises(InputError, match=r"another wall.*kitchen"):
        log.check_wall("def", "bath.yaml")
    log.close()
    with pytest.raises(InputError, match="already exists"):
        ScanLog.create(tmp_path / "scan.db", {"wall_fingerprint": "abc"})
    junk = tmp_path / "junk.db"
    junk.write_bytes(b"this is not sqlite at all" * 100)
    with pytest.raises(InputError, match="not a scan log"):
        ScanLog.open(junk)


def test_laser_fix_round_trip_and_version_1_logs_stay_readable(tmp_path):
    from scanner.laser import LASER_KEYS

    frame = {"frame_id": 0, "time_s": 0.0, "cmd_x_m": 0.0, "cmd_y_m": 0.0, "cmd_phi_rad": 0.0, "est_x_m": 0.0,
             "est_y_m": 0.0, "est_phi_rad": 0.0, "cov": np.eye(3) * 1e-6}
    fix = {k: 0.001 * (i + 1) for i, k in enumerate(LASER_KEYS)}
    log = ScanLog.create(tmp_path / "new.db", {"wall_fingerprint": "abc"})
    log.append_frame({**frame, **fix})
    log.append_frame({**frame, "frame_id": 1})  # no fix: NULL
    log.close()
    with ScanLog.open(tmp_path / "new.db") as back:
        assert back.meta["format"] == "arproj-scanlog/2"
        f = back.frames()
        for k, v in fix.items():
            assert f[k][0] == pytest.approx(v) and np.isnan(f[k][1])
    # A version 1 log: frames without the laser columns
    log = ScanLog.create(tmp_path / "old.db", {"wall_fingerprint": "abc"})
    log.close()
    db = sqlite3.connect(tmp_path / "old.db")
    for k in LASER_KEYS:
        db.execute(f"ALTER TABLE frames DROP COLUMN {k}")
    db.execute("UPDATE meta SET value = '\"arproj-scanlog/1\"' WHERE key = 'format'")
    db.commit()
    db.close()
    with ScanLog.open(tmp_path / "old.db", writable=True) as old:
        old.append_frame({**frame, **fix})  # resuming an old log: the fix is dropped, the frame kept
        f = old.frames()
        assert f["frame_id"].tolist() == [0] and all(np.isnan(f[k][0]) for k in LASER_KEYS)


# -------------------------------------------------------------------------------- one writer, whole creation
HOLD_LOG = ("import sys; from scanner.log import ScanLog; log = ScanLog.create(sys.argv[1], "
            "{'wall_fingerprint': 'first'}, overwrite=True); print('ready', flush=True); sys.stdin.read()")


def _holder(path):
    """A separate process that holds `path` open as its writer until its stdin closes."""
    import subprocess
    import sys
    from pathlib import Path

    proc = subprocess.Popen([sys.executable, "-c", HOLD_LOG, str(path)], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True, cwd=Path(__file__).resolve().parents[2])
    assert proc.stdout is not None and proc.stdout.readline().strip() == "ready"
    return proc


def test_a_second_writer_is_refused_naming_the_first_and_readers_keep_working(tmp_path):
    import os

    from scanner.log import LogInUseError

    path = tmp_path / "scan.db"
    first = ScanLog.create(path, {"wall_fingerprint": "first"})
    first.append_pass(_pass(0), _samples(10))
    for attempt in (lambda: ScanLog.create(path, {"wall_fingerprint": "second"}, overwrite=True),
                    lambda: ScanLog.open(path, writable=True)):
        with pytest.raises(LogInUseError, match=rf"another scan is writing this log \(pid {os.getpid()}"):
            attempt()
    with ScanLog.open(path) as reader:  # a reader beside the writer
        assert reader.meta["wall_fingerprint"] == "first" and len(reader.samples()["seq"]) == 10
    first.append_pass(_pass(1), _samples(5))  # the refusals took nothing from the first writer
    first.close()
    assert not (tmp_path / "scan.db.lock").exists()
    ScanLog.create(path, {"wall_fingerprint": "second"}, overwrite=True).close()  # free again: replaced
    with ScanLog.open(path) as back:
        assert back.meta["wall_fingerprint"] == "second" and back.pass_count() == 0


def test_a_writer_in_another_process_is_refused_and_its_lock_dies_with_it(tmp_path):
    import signal

    from scanner.log import LogInUseError

    path = tmp_path / "scan.db"
    holder = _holder(path)
    try:
        with pytest.raises(LogInUseError, match=rf"pid {holder.pid}: .*-c"):
            ScanLog.create(path, {"wall_fingerprint": "second"}, overwrite=True)
        with ScanLog.open(path) as reader:
            assert reader.meta["wall_fingerprint"] == "first"
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    assert (tmp_path / "scan.db.lock").exists()  # left behind by kill -9, but no longer locked
    with ScanLog.open(path, writable=True) as log:
        assert log.meta["wall_fingerprint"] == "first"


def test_overwrite_replaces_only_a_scan_log(tmp_path):
    text = tmp_path / "notes.txt"
    text.write_text("my notes\n")
    with pytest.raises(InputError, match=r"not a scan log.*--overwrite replaces only a scan log"):
        ScanLog.create(text, {"wall_fingerprint": "abc"}, overwrite=True)
    assert text.read_text() == "my notes\n"
    other = tmp_path / "other.db"
    db = sqlite3.connect(other)
    db.execute("CREATE TABLE t (x)")
    db.commit()
    db.close()
    with pytest.raises(InputError, match="tables meta/frames/passes/samples missing"):
        ScanLog.create(other, {"wall_fingerprint": "abc"}, overwrite=True)
    (tmp_path / "folder").mkdir()
    with pytest.raises(InputError, match="not a file"):
        ScanLog.create(tmp_path / "folder", {"wall_fingerprint": "abc"}, overwrite=True)
    assert not list(tmp_path.glob("*.lock"))  # every refusal let the lock go


def test_a_log_is_created_whole_or_not_at_all(tmp_path, monkeypatch):
    import os

    path = tmp_path / "scan.db"
    real_replace = os.replace

    def killed(*args):
        raise KeyboardInterrupt  # the process stops after building the new log, before it is moved in place

    monkeypatch.setattr(os, "replace", killed)
    with pytest.raises(KeyboardInterrupt):
        ScanLog.create(path, {"wall_fingerprint": "abc"})
    assert not path.exists() and (tmp_path / ".scan.db.creating").exists()
    with pytest.raises(InputError, match=r"stopped while creating it.*start it afresh"):
        ScanLog.open(path, writable=True)
    monkeypatch.setattr(os, "replace", real_replace)
    log = ScanLog.create(path, {"wall_fingerprint": "abc"})  # afresh: the leftover is replaced
    log.append_pass(_pass(0), _samples(10))
    log.close()
    monkeypatch.setattr(os, "replace", killed)
    with pytest.raises(KeyboardInterrupt):
        ScanLog.create(path, {"wall_fingerprint": "new"}, overwrite=True)
    monkeypatch.setattr(os, "replace", real_replace)
    with ScanLog.open(path, writable=True) as old:  # the old log is whole and resumable
        assert old.meta["wall_fingerprint"] == "abc" and old.pass_count() == 1
        assert len(old.samples()["seq"]) == 10
