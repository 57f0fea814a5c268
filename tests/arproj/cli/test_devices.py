"""`arproj devices serve` in a process of its own and `arproj scan` on its URLs: the samples and frames of
`arproj scan --sim` with the same seed, with faults too; Ctrl-C ends the server with one line, exit 130."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

from arproj.run.devices import read_urls
from scanner.log import ScanLog
from tests.support.processes import ctrl_c_default

WALL, SEED = "small_test_wall", 5
ENV = {**os.environ, "COLUMNS": "150"}


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-c", "from arproj.cli import main; main()", *args]


@contextmanager
def _served(tmp_path: Path, faults: float) -> Iterator[dict[str, str]]:
    urls_file = tmp_path / f"urls-{faults:g}.yaml"
    proc = subprocess.Popen(_cli("devices", "serve", "--wall", WALL, "--seed", str(SEED), "--faults", str(faults),
                                 "--urls", str(urls_file)), env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, preexec_fn=ctrl_c_default)
    try:
        deadline = time.monotonic() + 60
        while not urls_file.exists() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert urls_file.exists(), proc.communicate(timeout=5)
        yield read_urls(urls_file)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30)
        assert proc.returncode == 130, err
        assert out.strip().splitlines()[-1] == "arproj devices serve: stopped (Ctrl-C)"
        assert "socket://127.0.0.1:" in out and "Traceback" not in err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def _scan(log: Path, *args: str) -> str:
    done = subprocess.run(_cli("scan", "--wall", WALL, "--log", str(log), *args), env=ENV, capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    return done.stdout


def _assert_same_log(a: Path, b: Path) -> int:
    with ScanLog.open(a) as one, ScanLog.open(b) as other:
        samples, again = one.samples(), other.samples()
        frames, frames_again = one.frames(), other.frames()
        assert other.meta["status"] == "complete"
    assert samples.keys() == again.keys()
    for key, values in samples.items():
        np.testing.assert_array_equal(again[key], values, err_msg=key)
    assert frames.keys() == frames_again.keys()
    for key, values in frames.items():
        np.testing.assert_array_equal(np.asarray(frames_again[key]), np.asarray(values), err_msg=key)
    return len(samples["seq"])


@pytest.fixture(scope="module")
def sim_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    log = tmp_path_factory.mktemp("sim") / "sim.db"
    _scan(log, "--sim", "--seed", str(SEED))
    return log


def test_devices_served_by_another_process_give_the_sim_scan(tmp_path: Path, sim_log: Path) -> None:
    with _served(tmp_path, 0.0) as urls:
        assert set(urls) >= {"drives", "scanner", "laser", "base", "head"}
        out = _scan(tmp_path / "devices.db", "--drives", urls["drives"], "--scanner", urls["scanner"], "--laser",
                    urls["laser"], "--base", urls["base"], "--virtual-clock")
    assert "device faults recovered: 0" in out
    n = _assert_same_log(sim_log, tmp_path / "devices.db")
    assert n > 5000
    with ScanLog.open(tmp_path / "devices.db") as log:
        frames = log.frames()
        assert log.meta["seed"] is None  # a hardware log: the host knows no seed …
    assert np.all(np.isfinite(frames["true_x_m"]))  # … but the simulated base told the truth (TRUE?)
    assert np.all(np.abs(frames["laser_x_m"] - frames["true_x_m"]) < 5 * frames["laser_x_sigma_m"])


def test_faults_of_one_in_fifty_lines_lose_no_sample(tmp_path: Path, sim_log: Path) -> None:
    with _served(tmp_path, 0.02) as urls:
        out = _scan(tmp_path / "faulty.db", "--drives", urls["drives"], "--scanner", urls["scanner"], "--laser",
                    urls["laser"], "--base", urls["base"], "--virtual-clock", "--device-timeout", "0.05")
    recovered = int(out.split("device faults recovered:")[1].split()[0])
    print(f"device faults recovered: {recovered}")
    assert recovered > 100
    _assert_same_log(sim_log, tmp_path / "faulty.db")
