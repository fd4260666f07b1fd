"""The benchmarks write only their results, and those results name no machine's absolute paths."""

from __future__ import annotations

import ast
import json
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCHES = sorted((ROOT / "bench").glob("*.py"))
RESULTS = sorted((ROOT / "bench" / "results").glob("*.json"))


def code_strings(source: str) -> list[str]:
    """The string constants of ``source`` that are not docstrings."""
    tree = ast.parse(source)
    docstrings = {
        id(node.body[0].value)
        for node in ast.walk(tree)
        if isinstance(node, (ast.Module, ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef))
        and node.body
        and isinstance(node.body[0], ast.Expr)
        and isinstance(node.body[0].value, ast.Constant)
    }
    return [
        node.value
        for node in ast.walk(tree)
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docstrings
    ]


@pytest.mark.parametrize("bench", BENCHES, ids=lambda p: p.name)
def test_a_benchmark_names_no_document_in_its_code(bench):
    named = [s for s in code_strings(bench.read_text()) if re.search(r"(^|/)docs/|README", s)]
    assert not named, f"{bench.name} names documents it may write: {named}"


def strings(value):
    """Every string in a JSON document."""
    if isinstance(value, dict):
        for v in value.values():
            yield from strings(v)
    elif isinstance(value, list):
        for v in value:
            yield from strings(v)
    elif isinstance(value, str):
        yield value


@pytest.mark.parametrize("result", RESULTS, ids=lambda p: p.name)
def test_a_committed_result_holds_no_absolute_path(result):
    absolute = [s for s in strings(json.loads(result.read_text())) if re.match(r"/|[A-Za-z]:\\", s)]
    assert not absolute, f"{result.name}: {absolute}"


def test_shown_path_is_relative_to_the_repository_or_a_name(monkeypatch, tmp_path):
    monkeypatch.syspath_prepend(str(ROOT / "bench"))
    monkeypatch.delitem(sys.modules, "common", raising=False)
    from common import shown_path

    assert shown_path(ROOT) == "."
    assert shown_path(ROOT / "bench" / "results") == "bench/results"
    assert shown_path(tmp_path / "head-before") == "head-before"
