"""The link-scaling computation (benchmarks/link_scaling.py) against the closed loop's exchange."""

import importlib.util
import sys
from pathlib import Path

import pytest

from mrm_cosim.master.cycle import MasterTiming

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "link_scaling.py"
_spec = importlib.util.spec_from_file_location("link_scaling", _PATH)
scaling = importlib.util.module_from_spec(_spec)
sys.modules.setdefault("link_scaling", scaling)
_spec.loader.exec_module(scaling)

#: Computed and measured phase ends agree to this (two 20 ns cycles): the measured figures
#: are means over the run's periods, and the first period's VDC takes 289 cycles, not 282.
TOLERANCE_US = 0.04


def test_frame_time_is_the_line_time_of_46_characters_and_an_eop():
    assert scaling.frame_cycles(40) == 155            # 464 line bits at 3 per cycle
    assert scaling.frame_cycles(1) == 25


@pytest.mark.parametrize("robot, n", [("mrm3", 3), ("mrm6", 6)])
def test_computed_exchange_equals_the_measured_one(tmp_path, robot, n):
    measured = scaling.measure(robot, tmp_path / robot)
    assert measured["n"] == n
    computed = scaling.exchange(n).us()
    for key in ("A", "B", "C", "D", "end"):
        assert computed[key] == pytest.approx(measured[key], abs=TOLERANCE_US), key


def test_largest_n():
    timing = MasterTiming()
    n = scaling.largest_n(timing.period_cycles)
    assert scaling.exchange(n).end <= timing.period_cycles < scaling.exchange(n + 1).end
    assert n == 75
    assert scaling.largest_n(10_000) == 12            # Comm D before the default commit phase
    slower = MasterTiming(kinematics_cycles=10_000, force_cycles=10_000)
    assert scaling.largest_n(timing.period_cycles, slower) < n
    with pytest.raises(ValueError):
        scaling.exchange(0)
