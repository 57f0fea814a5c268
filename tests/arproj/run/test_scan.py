"""The scan run functions: a wall by file or shipped name, and the settings a log records and gives back."""

from pathlib import Path

import pytest

from arproj.run.scan import ScanSettings, new_scan_log, resolve_wall
from geometry.errors import InputError
from scanner.log import ScanLog
from scanner.wall import shipped_walls


def test_a_shipped_wall_by_name_and_a_missing_file_named_with_the_choices(tmp_path: Path) -> None:
    wall, path = resolve_wall("paper_test_plate")
    assert path == shipped_walls()["paper_test_plate"] and wall.fingerprint()
    assert resolve_wall(path)[1] == path  # a file is taken as it is
    with pytest.raises(InputError, match="no such file") as err:
        resolve_wall(tmp_path / "nowhere.yaml")
    assert "small_test_wall" in str(err.value)


def test_a_resumed_log_gives_back_the_settings_it_was_made_with(tmp_path: Path) -> None:
    wall, path = resolve_wall("small_test_wall")
    settings = ScanSettings(plan="adaptive", plan_options={"priors": False, "coarse_row_spacing_m": 0.2}, seed=7,
                            serial=False)
    new_scan_log(tmp_path / "scan.db", wall, str(path), settings).close()
    with ScanLog.open(tmp_path / "scan.db") as log:
        again = ScanSettings.from_log(log.meta, tmp_path / "scan.db")
    assert (again.plan, again.seed, again.sensor, again.drives) == ("adaptive", 7, settings.sensor, settings.drives)
    assert again.plan_options["priors"] is False and again.plan_options["coarse_row_spacing_m"] == 0.2
    with pytest.raises(InputError, match="not made on the simulated site"):
        ScanSettings.from_log({**log.meta, "seed": None}, "hardware.db")
