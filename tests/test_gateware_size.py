"""Gateware stays readable: no function in a gateware module is longer than 150 lines.

A gateware module is a ``.py`` file under ``hdl/`` that imports Amaranth. An ``elaborate``
that outgrows the limit is split into sub-components with their own signatures, or into
helper methods, one job each (docs/node.md "Structure"; issue 14, item 6).
"""

import ast
from pathlib import Path

HDL = Path(__file__).resolve().parents[1] / "hdl"
MAX_LINES = 150


def imports_amaranth(tree: ast.AST) -> bool:
    """Whether a module imports ``amaranth`` or one of its submodules."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            if any(a.name.split(".")[0] == "amaranth" for a in node.names):
                return True
        elif isinstance(node, ast.ImportFrom):
            if node.level == 0 and (node.module or "").split(".")[0] == "amaranth":
                return True
    return False


def long_functions(source: str, where: str, limit: int = MAX_LINES) -> list[str]:
    """``where:line qualified.name (n lines)`` of every function longer than ``limit`` lines,
    nested functions and methods included; none if the module does not import Amaranth."""
    tree = ast.parse(source)
    if not imports_amaranth(tree):
        return []
    found = []

    def visit(node, prefix):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                name = f"{prefix}{child.name}"
                if not isinstance(child, ast.ClassDef):
                    n = child.end_lineno - child.lineno + 1
                    if n > limit:
                        found.append(f"{where}:{child.lineno} {name} ({n} lines)")
                visit(child, name + ".")
            else:
                visit(child, prefix)

    visit(tree, "")
    return found


def test_no_long_gateware_function():
    files = sorted(HDL.rglob("*.py"))
    assert files, f"no Python files under {HDL}"
    offenders = [hit for path in files
                 for hit in long_functions(path.read_text(encoding="utf-8"),
                                           str(path.relative_to(HDL.parent)))]
    assert not offenders, (f"gateware functions longer than {MAX_LINES} lines (split them into "
                           f"sub-components or helpers): " + "; ".join(offenders))


def _function(name: str, lines: int, indent: str = "") -> str:
    body = "".join(f"{indent}    x{k} = {k}\n" for k in range(lines - 2))
    return f"{indent}def {name}():\n{body}{indent}    return 0\n"


def test_checker_names_a_long_method_of_a_gateware_module():
    source = ("from amaranth import *\n\n\nclass Block:\n" + _function("elaborate", 151, "    ")
              + _function("short", 150))
    assert long_functions(source, "x.py") == ["x.py:5 Block.elaborate (151 lines)"]


def test_checker_finds_nested_functions_and_skips_other_modules():
    nested = "import amaranth.lib.wiring\n\n\ndef outer():\n" + _function("inner", 151, "    ")
    assert long_functions(nested, "y.py") == ["y.py:4 outer (152 lines)",
                                              "y.py:5 outer.inner (151 lines)"]
    assert long_functions(_function("reference", 400), "ref.py") == []
