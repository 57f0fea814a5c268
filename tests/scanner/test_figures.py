"""Pictures: the paper's figures re-made, and a scan log drawn on the wall."""

import numpy as np
from PIL import Image

from scanner.figures import _crossing_x, plot_log, plot_paper_figures
from scanner.log import ScanLog
from scanner.plan import DriveConfig, make_planner
from scanner.run import DirectBackend, run_scan, scan_meta, simulated_site
from scanner.sensor_model import SensorConfig
from scanner.wall import load_wall, shipped_walls


def test_paper_figures_and_log_plot_are_written(tmp_path):
    out = plot_paper_figures(tmp_path / "paper.png")
    assert Image.open(out).size[0] > 800  # a multi-panel figure, not a thumbnail
    wall = load_wall(shipped_walls()["small_test_wall"])
    sensor, drives = SensorConfig(), DriveConfig()
    log = ScanLog.create(tmp_path / "s.db", scan_meta(wall, "small", make_planner("adaptive", wall, drives)
                                                      .describe(), sensor, drives, 0, simulated=True))
    world, robot = simulated_site(wall, sensor, drives, 0)
    run_scan(wall, DirectBackend(world), robot, plan_kind="adaptive", sensor=sensor, drives=drives, log=log)
    log.close()
    picture = np.asarray(Image.open(plot_log(tmp_path / "s.db", tmp_path / "s.png")).convert("L"))
    assert picture.std() > 10  # not a blank canvas: 10 of 255 grey levels


def test_crossing_of_the_45_degree_pipe():
    assert _crossing_x(np.array([[0.5, 0.0], [1.1, 0.6]]), 0.3) == 0.8
    assert _crossing_x(np.array([[0.5, 0.0], [1.1, 0.6]]), 0.9) is None
