"""`mrm run table2` takes the experiment's ``[safety]`` as `mrm run track` does: its line
faults, what the master does on a trip and the nodes' safe stop reach every controller's run,
or are refused by field — never dropped (issue 22)."""

from __future__ import annotations

import pytest

from mrm_cosim.cosim.experiment_config import loads
from mrm_cosim.cosim.table2 import _run_kwargs
from mrm_cosim.cosim.track import run_track
from mrm_cosim.errors import InputError
from mrm_cosim.models.robot import load_robot
from mrm_cosim.protocol.safe_stop import SafeStopParams

BASE = """
[experiment]
robot = "mrm3"
backend = "{backend}"
"""


def _config(backend="model", safety=""):
    return loads(BASE.format(backend=backend) + safety)


def test_safety_reaches_the_runner():
    cfg = _config(safety='[safety]\nline_faults = ["cut:down:1@0.5s+5ms"]\n'
                         'on_trip = "end"\nrearm_blend = 0.3\nstop_s = 0.07\n')
    kw = _run_kwargs(run_track, cfg, load_robot("mrm3"))
    assert kw["on_trip"] == "end" and kw["rearm_blend"] == 0.3
    assert kw["safe_stop"] == SafeStopParams(stop_s=0.07)
    (f,) = kw["faults"]
    assert (f.kind, f.direction, f.node) == ("cut", "down", 1)


def test_defaults_are_the_runners_own():
    kw = _run_kwargs(run_track, _config(), load_robot("mrm3"))
    assert "faults" not in kw
    assert kw["safe_stop"] == SafeStopParams() and kw["on_trip"] == "rearm"


@pytest.mark.parametrize("fault, message", [
    ("bit:down:1@0.5s", "'cut' faults only"),
    ("cut:down:4@0.5s", "3 nodes, not 4"),
])
def test_refused_by_field(fault, message):
    cfg = _config(safety=f'[safety]\nline_faults = ["{fault}"]\n')
    with pytest.raises(InputError, match=message) as e:
        _run_kwargs(run_track, cfg, load_robot("mrm3"))
    assert e.value.field == "safety.line_faults"


def test_a_runner_without_faults_refuses_them():
    def runner(robot, controller, backend, duration, seed, **kw):
        raise AssertionError("not reached")

    cfg = _config(safety='[safety]\nline_faults = ["cut:down:1@0.5s"]\n')
    with pytest.raises(InputError) as e:
        _run_kwargs(runner, cfg, load_robot("mrm3"))
    assert e.value.field == "safety.line_faults"
