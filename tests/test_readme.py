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


def test_ci_fails_when_any_step_of_the_test_command_fails(tmp_path):
    """The README's command is an && list, and `set -e` ignores a failure inside one: a ruff
    failure skipped the tests and CI still ended green. .ci/run runs it in a subshell, whose
    failure stops the script: here with a failing step put in the list's place."""
    import subprocess

    _, tests = readme_commands()
    lines = (ROOT / ".ci" / "run").read_text().splitlines()
    i = lines.index(tests)
    assert lines[i - 1] == "(" and lines[i + 1] == ")"
    script = tmp_path / "run"
    body = lines[:i] + ["true && false && true"] + lines[i + 1:i + 2] + ["echo reached"]
    script.write_text("\n".join(line for line in body
                                if not line.startswith(("if ", "  (", "    ||", "fi"))) + "\n")
    run = subprocess.run(["bash", str(script)], capture_output=True, text=True, cwd=tmp_path)
    assert run.returncode != 0 and "reached" not in run.stdout


def test_readme_main_job_is_a_valid_mrm_command():
    main_job, _ = readme_commands()
    assert main_job.startswith("python3.11 -m venv .venv")
    mrm = main_job.split("&& .venv/bin/mrm ", 1)[1]
    build_parser().parse_args(shlex.split(mrm))
