"""The README's two commands stay true: CI runs the test command verbatim, the main job parses."""

import re
import shlex
from pathlib import Path

from mrm_cosim.mrm.cli import build_parser

ROOT = Path(__file__).parents[1]


def readme_commands() -> list[str]:
    text = (ROOT / "README.md").read_text()
    return re.findall(r"```sh\n(.*?)\n```", text, re.S)[:2]


def test_ci_runs_the_readme_test_command_verbatim():
    main_job, tests = readme_commands()
    assert "pytest" in tests and "venv .venv" in tests
    ci = (ROOT / ".ci" / "run").read_text()
    assert tests in ci.splitlines()


def test_readme_main_job_is_a_valid_mrm_command():
    main_job, _ = readme_commands()
    assert main_job.startswith("python3.11 -m venv .venv")
    mrm = main_job.split("&& .venv/bin/mrm ", 1)[1]
    build_parser().parse_args(shlex.split(mrm))
