"""Sizes that keep the code readable: no library module over 40 KB, no function over 80 lines
(the benchmark and its synthetic world generator, bench/ and synth/, are exempt from the latter)."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "rose_usd"
MAX_MODULE_BYTES = 40_000
MAX_FUNCTION_LINES = 80
EXEMPT = {"bench", "synth"}


def long_functions(source: str, limit: int = MAX_FUNCTION_LINES) -> list[tuple[str, int]]:
    """(name, lines) of every function or method in ``source`` longer than ``limit`` lines."""
    return [
        (node.name, node.end_lineno - node.lineno + 1)
        for node in ast.walk(ast.parse(source))
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.end_lineno - node.lineno + 1 > limit
    ]


def _library_modules():
    return sorted(PACKAGE.rglob("*.py"))


def test_no_module_is_over_40_kb():
    big = [
        f"{p.relative_to(PACKAGE.parent)}: {p.stat().st_size} B"
        for p in _library_modules()
        if p.stat().st_size > MAX_MODULE_BYTES
    ]
    assert not big, "split these modules: " + "; ".join(big)


def test_no_function_is_over_80_lines():
    found = []
    for path in _library_modules():
        rel = path.relative_to(PACKAGE)
        if rel.parts[0] in EXEMPT:
            continue
        found += [f"{rel}:{name} ({n} lines)" for name, n in long_functions(path.read_text())]
    assert not found, "split these functions: " + "; ".join(found)


def test_a_long_function_is_caught():
    body = "\n".join(f"    x{i} = {i}" for i in range(MAX_FUNCTION_LINES))
    assert long_functions(f"def f():\n{body}\n") == [("f", MAX_FUNCTION_LINES + 1)]
    assert long_functions(f"def f():\n{body}\n", limit=MAX_FUNCTION_LINES + 1) == []
