"""The bad-input corpus (tests/bad_input_cases.py): every case is refused with exit code 2,
one line on stderr naming the field, no traceback, and nothing written."""

import pytest

from tests.bad_input_cases import CASES
from mrm_cosim.mrm.cli import main


def test_the_corpus_is_large_and_its_ids_unique():
    ids = [c[0] for c in CASES]
    assert len(ids) >= 150
    assert len(set(ids)) == len(ids)


def test_the_readme_states_the_corpus_size():
    """README: "a corpus of N cases in the tests" stays true as cases are added."""
    import re
    from pathlib import Path

    text = (Path(__file__).parents[1] / "README.md").read_text()
    m = re.search(r"a corpus of ([\d,]+) cases", text)
    assert m and int(m.group(1).replace(",", "")) == len(CASES), (m and m.group(0), len(CASES))


@pytest.mark.parametrize("argv, files, field", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_bad_input_is_refused_in_one_line(tmp_path, capsys, argv, files, field):
    paths = {}
    for name, text in files.items():
        path = tmp_path / (f"{name[:-4]}.csv" if name.endswith("_csv") else f"{name}.toml")
        path.write_bytes(text.encode("utf-8", "surrogateescape"))
        paths[name] = str(path)
    out = tmp_path / "out"
    argv = [a.format(out=out, **paths) for a in argv]
    before = sorted(tmp_path.iterdir())
    with _exit_code() as code:
        code.value = main(argv)
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert code.value == 2, (argv, captured.err)
    assert len(lines) == 1, captured.err
    assert "Traceback" not in captured.err
    assert field in lines[0], (field, lines[0])
    assert not out.exists()
    assert sorted(tmp_path.iterdir()) == before


class _exit_code:
    """``main`` returns the code, argparse's refusals raise ``SystemExit(2)``: both count."""

    value = None

    def __enter__(self):
        return self

    def __exit__(self, kind, exc, tb):
        if kind is SystemExit:
            self.value = exc.code
            return True
        return False
