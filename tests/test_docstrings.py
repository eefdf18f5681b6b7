"""The public API is documented in numpy style (issue 15 item 5; docs/STYLE: numpy's docstrings).

Read with ``ast`` (nothing is imported). Public means a name without a leading underscore,
in a module whose path has none (``__init__`` aside), in the project's packages. Each public
module, class, function and method has a docstring; one that takes two or more arguments
(``self``/``cls`` aside) says what they are in a ``Parameters`` section -- a class's in its
own docstring or its ``__init__``'s, as numpy's guide allows. A method that overrides a
documented method of a project class it derives from inherits that documentation, as
``inspect.getdoc`` would give it; property setters are documented by their getter.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = (
    "settings", "devices", "hub", "sim_network", "sim_robot", "adapters", "lab", "neuvision",
    "dashboard",
)  # fmt: skip


def public_modules(root: Path = ROOT) -> list[Path]:
    """The project's modules whose path has no private part."""
    found = []
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            parts = path.relative_to(root).parts
            if not any(p.startswith("_") and p != "__init__.py" for p in parts):
                found.append(path)
    return found


def n_arguments(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    """Arguments a caller passes (``self``/``cls`` and ``**kwargs`` aside)."""
    a = fn.args
    names = [x.arg for x in a.posonlyargs + a.args + a.kwonlyargs]
    if names and names[0] in ("self", "cls"):
        names = names[1:]
    return len(names) + (a.vararg is not None)


def _decorators(fn) -> set[str]:
    names = set()
    for d in fn.decorator_list:
        if isinstance(d, ast.Name):
            names.add(d.id)
        elif isinstance(d, ast.Attribute):
            names.add(d.attr)
    return names


def _has_parameters(doc: str | None) -> bool:
    return bool(doc) and "\nParameters\n" in f"\n{doc}\n"


class Classes:
    """Every class of the project by name: its bases' names and its documented methods."""

    def __init__(self, modules: list[Path]):
        self.bases: dict[str, list[str]] = {}
        self.documented: dict[str, set[str]] = {}
        for path in modules:
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.ClassDef):
                    self.bases[node.name] = [
                        b.id if isinstance(b, ast.Name) else getattr(b, "attr", "")
                        for b in node.bases
                    ]
                    self.documented[node.name] = {
                        n.name
                        for n in node.body
                        if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef)
                        and ast.get_docstring(n)
                    }

    def inherits_doc(self, cls: str, method: str) -> bool:
        """Whether a project class ``cls`` derives from documents ``method``."""
        seen, todo = set(), list(self.bases.get(cls, []))
        while todo:
            base = todo.pop()
            if base in seen:
                continue
            seen.add(base)
            if method in self.documented.get(base, ()):
                return True
            todo += self.bases.get(base, [])
        return False


def problems(path: Path, classes: Classes, root: Path = ROOT) -> list[str]:
    """What the public API of one module lacks, one line each (``file:line name: what``)."""
    tree = ast.parse(path.read_text())
    where = path.relative_to(root)
    out = []
    if not ast.get_docstring(tree) and path.read_text().strip():
        out.append(f"{where}:1 module: no docstring")

    def visit(body, cls: ast.ClassDef | None) -> None:
        for node in body:
            if isinstance(node, ast.ClassDef) and not node.name.startswith("_"):
                doc = ast.get_docstring(node)
                if not doc:
                    out.append(f"{where}:{node.lineno} class {node.name}: no docstring")
                init = next(
                    (n for n in node.body
                     if isinstance(n, ast.FunctionDef) and n.name == "__init__"),
                    None,
                )  # fmt: skip
                if (
                    init is not None
                    and n_arguments(init) >= 2
                    and not _has_parameters(doc)
                    and not _has_parameters(ast.get_docstring(init))
                ):
                    out.append(f"{where}:{node.lineno} class {node.name}: no Parameters")
                visit(node.body, node)
            elif isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                if node.name.startswith("_"):
                    continue
                decorators = _decorators(node)
                if "setter" in decorators or "deleter" in decorators or "overload" in decorators:
                    continue
                if cls is not None and classes.inherits_doc(cls.name, node.name):
                    continue
                name = f"{cls.name}.{node.name}" if cls else node.name
                doc = ast.get_docstring(node)
                if not doc:
                    out.append(f"{where}:{node.lineno} {name}: no docstring")
                elif n_arguments(node) >= 2 and not _has_parameters(doc):
                    out.append(f"{where}:{node.lineno} {name}: no Parameters")

    visit(tree.body, None)
    return out


def test_every_public_name_is_documented_with_its_parameters():
    modules = public_modules()
    classes = Classes(modules)
    found = [p for path in modules for p in problems(path, classes)]
    assert not found, f"{len(found)} public names undocumented:\n" + "\n".join(found)


def test_the_check_finds_an_undocumented_function_and_a_missing_parameters_section(tmp_path):
    package = tmp_path / "hub"
    package.mkdir()
    (package / "planted.py").write_text(
        '"""A module."""\n\n'
        "def bare(a):\n    return a\n\n"
        'def two(a, b):\n    """Adds."""\n    return a + b\n\n'
        'def fine(a, b):\n    """Adds.\n\n    Parameters\n    ----------\n    a, b : int\n    """\n'
    )
    classes = Classes([package / "planted.py"])
    assert problems(package / "planted.py", classes, tmp_path) == [
        "hub/planted.py:3 bare: no docstring",
        "hub/planted.py:6 two: no Parameters",
    ]


@pytest.mark.parametrize("method_doc, expected", [('"""Step."""', []), ("", ["no docstring"])])
def test_an_override_inherits_its_base_methods_documentation(tmp_path, method_doc, expected):
    path = tmp_path / "m.py"
    path.write_text(
        '"""A module."""\n\n'
        'class Base:\n    """A base."""\n\n'
        f"    def step(self, a, b):\n        {method_doc or 'pass'}\n\n"
        'class Child(Base):\n    """A child."""\n\n    def step(self, a, b):\n        return a\n'
    )
    found = problems(path, Classes([path]), tmp_path)
    assert [line.split(": ", 1)[1] for line in found if "Child" in line] == expected
