"""The one TOML reader: every broken file is one InputError naming the argument and the file."""

import pytest

from mrm_cosim.errors import InputError
from mrm_cosim.mrm.cli import main
from mrm_cosim.tomlfile import MAX_BYTES, MAX_DEPTH, parse_toml, read_toml


@pytest.mark.parametrize("text, words", [
    ("a = 1\na = 2\n", "the key 'a' is given more than once (again on line 2)"),
    ("[gains]\nK = 1\nlam = 3\nK = 3\n[x]\ny = 1\n",
     "the key 'gains.K' is given more than once (again on line 4)"),
    ("[t]\nx = 1\n[t]\ny = 2\n", "the table 't' is declared more than once (again on line 3)"),
    ("p = { a = 1, a = 2 }\n", "Duplicate inline table key 'a'"),
    ("a = " + "[" * 3000 + "]" * 3000 + "\n", f"at most {MAX_DEPTH} levels"),
    ("a = " + "{b = " * 100 + "1" + "}" * 100 + "\n", f"at most {MAX_DEPTH} levels"),
    ("[" + ".".join("abcdefghijklmnopqr") + "]\nx = 1\n", f"at most {MAX_DEPTH} levels"),
    ("a = [1, 2\n", "not valid TOML"),
])
def test_broken_documents_are_named(text, words):
    with pytest.raises(InputError) as info:
        parse_toml(text, "config", "'c.toml'")
    assert info.value.field == "config"
    assert words in info.value.message and "'c.toml'" in info.value.message


@pytest.mark.parametrize("text", [
    "[[m]]\nx = 1\n[[m]]\nx = 2\n",
    "pose = [\n  [1, 0],\n  [0, 1],\n]\n",
    's = "[[[[[[[[[[[[[[[[[[[[[[[[[["\n# [[[[[[[[[[[[[[[[[[[[[[[[[[[[\n',
    "a = " + "[" * MAX_DEPTH + "]" * MAX_DEPTH + "\n",
])
def test_ordinary_documents_are_read_as_tomllib_reads_them(text):
    import tomllib

    assert parse_toml(text, "config") == tomllib.loads(text)


def test_files_that_are_not_descriptions(tmp_path):
    latin1 = tmp_path / "latin1.toml"
    latin1.write_bytes("name = 'Müller'\n".encode("latin-1"))
    big = tmp_path / "big.toml"
    big.write_bytes(b"# " + b"x" * MAX_BYTES + b"\n")
    cases = {latin1: "is not UTF-8 text (byte 0xfc at offset 9)",
             big: "larger than 1024 KiB", tmp_path: "is a folder",
             tmp_path / "missing.toml": "does not exist"}
    for path, words in cases.items():
        with pytest.raises(InputError) as info:
            read_toml(path, "robot")
        assert info.value.field == "robot" and words in info.value.message, path


@pytest.mark.parametrize("argv", [
    ["robot", "show", "{f}"],
    ["run", "track", "--config", "{f}", "--out", "{out}"],
    ["plan", "line", "{f}"],
])
def test_every_command_reading_toml_refuses_in_one_line(tmp_path, capsys, argv):
    f = tmp_path / "bad.toml"
    f.write_bytes(b"name = 'x'\nname = 'y'\n")
    out = tmp_path / "out"
    code = main([a.format(f=f, out=out) for a in argv])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert "the key 'name' is given more than once" in err[0]
    assert not out.exists()
