"""``mrm run dmp-table2`` end to end on a short configuration: one path, one slow period."""

import json

from mrm_cosim.cosim.dmp_table2 import (DMP_CONFIG, PAPER_RMSE, load_dmp_config,
                                        loads_dmp_config, paper_error)
from mrm_cosim.mrm.cli import main

SHORT = """
[experiment]
robot = "mrm6"
backend = "model"
periods_ms = [10]
hold = 0.05

[dmp]
basis = 20

[[path]]
name = "line"
shape = "line"
length = 0.02
duration = 0.3
"""


def test_the_package_config_is_the_papers_four_paths():
    cfg = load_dmp_config(DMP_CONFIG)
    assert [p.name for p in cfg.paths] == list(PAPER_RMSE) and cfg.periods_ms[0] == 50
    assert cfg.robot == "mrm6" and cfg.controller == "pid-fpga"
    assert loads_dmp_config(SHORT).paths[0].size == {"length": 0.02}


def test_paper_error_is_a_difference_of_logarithms_not_a_distance():
    """Eq. (10) subtracts two logarithms: the same relative error gives different values at
    different places (it depends on the base frame), unlike ‖log(T_d⁻¹ T_g)‖."""
    import numpy as np

    from mrm_cosim.master.cartesian import se3_log

    def pose(angle, x):
        c, s = np.cos(angle), np.sin(angle)
        T = np.eye(4)
        T[:2, :2] = [[c, -s], [s, c]]
        T[0, 3] = x
        return T

    d = pose(0.01, 0.0)                       # 10 mrad about z
    near = paper_error(np.eye(4), d)
    far = paper_error(pose(2.5, 0.5), pose(2.5, 0.5) @ d)
    rel_near = np.linalg.norm(se3_log(np.linalg.inv(np.eye(4)) @ d))
    rel_far = np.linalg.norm(se3_log(np.linalg.inv(pose(2.5, 0.5)) @ pose(2.5, 0.5) @ d))
    assert abs(rel_near - rel_far) < 1e-12 and abs(near - 0.01) < 1e-12
    assert abs(far - near) > 0.05 * near          # 6 % here, for the same relative error


def test_run_writes_the_table_and_the_plots(tmp_path, capsys):
    cfg = tmp_path / "short.toml"
    cfg.write_text(SHORT)
    out = tmp_path / "out"
    assert main(["run", "dmp-table2", "--config", str(cfg), "--out", str(out), "--jobs", "1",
                 "-q"]) == 0
    for name in ("summary.json", "dmp_table2.md", "config.toml", "paths_10ms.png",
                 "errors.png"):
        assert (out / name).stat().st_size > 0
    s = json.loads((out / "summary.json").read_text())
    runs = {(r["architecture"], r["period_ms"]): r for r in s["paths"]["line"]["runs"]}
    assert set(runs) == {("traditional", 10), ("feedforward", 10), ("modularized", 10),
                         ("reference", 1)}
    assert all(r["dmp_errors"] == 0 and r["upload_errors"] == 0 for r in runs.values())
    assert runs[("modularized", 10)]["paper"] < runs[("traditional", 10)]["paper"]
    assert runs[("modularized", 10)]["relative"] < runs[("traditional", 10)]["relative"]
    assert "| line | modularized | 10 ms |" in (out / "dmp_table2.md").read_text()
