"""`arproj scan` under a second writer and Ctrl-C (issue 24 items 1, 2): a second writer or an --overwrite of a
log being written is refused with one line naming the first's pid, the log untouched; Ctrl-C at start-up or
mid-scan exits 130 with one line, and the log resumes."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from scanner.log import ScanLog
from tests.support.processes import ctrl_c_default

ROOT = Path(__file__).resolve().parents[3]
EXE = Path(sys.executable).parent / "arproj"
SCAN = ["scan", "--sim", "--wall", "small_test_wall", "--plan", "dense"]
HOLD_LOG = ("import sys; from scanner.log import ScanLog; log = ScanLog.create(sys.argv[1], "
            "{'wall_fingerprint': 'first'}); print('ready', flush=True); sys.stdin.read()")

pytestmark = pytest.mark.skipif(not EXE.exists(), reason="the arproj console script is not installed here")


def _arproj(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(EXE), *args], capture_output=True, text=True, timeout=300, cwd=ROOT)


def _error_lines(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if "arproj:" in line]


def test_overwrite_and_resume_of_a_log_being_written_are_refused(tmp_path: Path) -> None:
    log = tmp_path / "scan.db"
    holder = subprocess.Popen([sys.executable, "-c", HOLD_LOG, str(log)], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "ready"
        for args in ([*SCAN, "--log", str(log), "--overwrite", "--fast"], ["scan", "--resume", str(log)]):
            run = _arproj(*args)
            assert run.returncode == 2, run.stderr
            assert "Traceback" not in run.stderr
            errors = _error_lines(run.stderr)
            assert len(errors) == 1 and f"another scan is writing this log (pid {holder.pid}:" in errors[0]
        with ScanLog.open(log) as back:  # the first writer's log, untouched
            assert back.meta["wall_fingerprint"] == "first" and back.pass_count() == 0
    finally:
        holder.kill()
        holder.wait()
    run = _arproj(*SCAN, "--log", str(log), "--overwrite", "--fast")  # its writer gone: replaced
    assert run.returncode == 0, run.stderr
    assert f"{log}: replaced by a new scan log" in run.stdout


def test_overwrite_never_replaces_another_file(tmp_path: Path) -> None:
    notes = tmp_path / "notes.txt"
    notes.write_text("keep me\n")
    run = _arproj(*SCAN, "--log", str(notes), "--overwrite", "--fast")
    assert run.returncode == 2 and len(_error_lines(run.stderr)) == 1 and "not a scan log" in run.stderr
    assert notes.read_text() == "keep me\n"


def _wait_for(condition, proc: subprocess.Popen[str]) -> None:
    while not condition():
        assert proc.poll() is None, "arproj ended before the moment to interrupt it"
        time.sleep(0.005)


def _loaded(pid: int, library: str) -> bool:
    try:
        return library in Path(f"/proc/{pid}/maps").read_text()
    except OSError:
        return False


@pytest.mark.skipif(not Path("/proc/self/maps").exists(), reason="needs /proc to see how far start-up got")
def test_ctrl_c_while_starting_and_while_scanning_is_one_line_and_130(tmp_path: Path) -> None:
    log = tmp_path / "scan.db"
    moments = {  # numpy's core loads while the commands are imported; the log exists once the scan runs
        "start-up": lambda proc: _loaded(proc.pid, "_multiarray_umath"),
        "scan": lambda proc: log.exists(),
    }
    for moment, reached in moments.items():
        proc = subprocess.Popen([str(EXE), *SCAN, "--log", str(log)], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, cwd=ROOT, preexec_fn=ctrl_c_default)
        _wait_for(lambda proc=proc, reached=reached: reached(proc), proc)
        proc.send_signal(signal.SIGINT)
        _, stderr = proc.communicate(timeout=120)
        assert proc.returncode == 130, (moment, stderr)
        errors = _error_lines(stderr)
        assert "Traceback" not in stderr and len(errors) == 1, stderr
        assert errors[0] in ("arproj: interrupted (Ctrl-C) while starting", "arproj: interrupted (Ctrl-C)"), stderr
    run = _arproj("scan", "--resume", str(log))
    assert run.returncode == 0, run.stderr
    assert "resuming after" in run.stdout or "no pass recorded yet" in run.stdout
    with ScanLog.open(log) as back:
        assert back.meta["status"] == "complete" and back.pass_count() > 0
