"""The code's shape: no function in ao4d/, datasets_gen/ or bench/ over 100 lines of code.

A function's code lines are the lines of its body, nested functions and classes included, less
its docstring, comments and blank lines (its signature and decorators are not counted).
"""

from __future__ import annotations

import ast
import io
import tokenize
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("ao4d", "datasets_gen", "bench")
MAX_LINES = 100

# functions allowed over the limit, by "path:name", each with its reason (none today)
ALLOWED: set[str] = set()


def _sources() -> list[Path]:
    return sorted(path for package in PACKAGES for path in (ROOT / package).rglob("*.py"))


def _docstring_lines(node: ast.AST) -> set[int]:
    body = getattr(node, "body", None)
    if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
        if isinstance(body[0].value.value, str):
            return set(range(body[0].lineno, body[0].end_lineno + 1))
    return set()


def _code_lines(source: str) -> set[int]:
    """The lines that hold a token other than a comment, a newline or indentation."""
    skip = {tokenize.COMMENT, tokenize.NL, tokenize.NEWLINE, tokenize.INDENT, tokenize.DEDENT, tokenize.ENDMARKER}
    lines: set[int] = set()
    for token in tokenize.generate_tokens(io.StringIO(source).readline):
        if token.type not in skip:
            lines.update(range(token.start[0], token.end[0] + 1))
    return lines


def function_lengths(source: str) -> dict[str, int]:
    """Code lines of each function in ``source``, by its qualified name (``Class.method``,
    ``outer.inner``)."""
    tree = ast.parse(source)
    code = _code_lines(source)
    docstrings: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef, ast.Module)):
            docstrings |= _docstring_lines(node)
    lengths: dict[str, int] = {}

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                name = prefix + child.name
                if not isinstance(child, ast.ClassDef):
                    first = child.body[0]
                    start = min([first.lineno] + [d.lineno for d in getattr(first, "decorator_list", [])])
                    body = set(range(start, child.end_lineno + 1))
                    lengths[name] = len((body & code) - docstrings)
                visit(child, name + ".")
            else:
                visit(child, prefix)

    visit(tree, "")
    return lengths


def test_counts_code_lines_only():
    source = '''
def f(x):
    """Docstring,

    over lines.
    """
    # a comment

    y = (x +
         1)
    return y
'''
    assert function_lengths(source) == {"f": 3}


def test_counts_nested_functions_in_their_outer_function():
    source = "class A:\n    def m(self):\n        def g():\n            return 1\n\n        return g\n"
    assert function_lengths(source) == {"A.m": 3, "A.m.g": 1}


def test_no_function_over_100_lines():
    long = {}
    for path in _sources():
        relative = path.relative_to(ROOT).as_posix()
        for name, n in function_lengths(path.read_text(encoding="utf-8")).items():
            if n > MAX_LINES and f"{relative}:{name}" not in ALLOWED:
                long[f"{relative}:{name}"] = n
    assert not long, f"functions over {MAX_LINES} lines of code (split them into named steps): {long}"
