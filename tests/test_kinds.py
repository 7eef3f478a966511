"""The model kinds (sonicskin.kinds): one registry, each kind one module; the rest of the package names no kind."""

from __future__ import annotations

import ast
import tokenize
from pathlib import Path

import pytest

from sonicskin import kinds

ROOT = Path(__file__).resolve().parents[1]
#: the registry and the two kinds' own modules (the network's runtime half, and its fit and export)
OWN = {"sonicskin/kinds/__init__.py", "sonicskin/kinds/svm.py", "sonicskin/kinds/net.py", "training/fit.py"}


def _kind_literals(path: Path) -> list[int]:
    """Lines of string literals that are exactly a kind's name (docstrings and prose are longer strings)."""
    with tokenize.open(path) as f:
        return [tok.start[0] for tok in tokenize.generate_tokens(f.readline)
                if tok.type == tokenize.STRING and tok.string.strip("\"'") in ("net", "svm")
                and tok.string[0] in "\"'" and len(tok.string) in (5, 7)]


def test_kind_names_are_literals_only_in_the_registry_and_the_kinds_modules():
    hits = {str(p.relative_to(ROOT)): lines for d in ("sonicskin", "models", "training", "export") for p in (ROOT / d).rglob("*.py")
            if str(p.relative_to(ROOT)) not in OWN and (lines := _kind_literals(p))}
    assert hits == {}, "name the kind through sonicskin.kinds (BASELINE, NETWORK, the registry), not as a literal"


def test_the_registry_has_the_three_kinds_each_with_its_own_head_and_graph():
    assert kinds.names() == ["net", "svm", "lda"]  # report order: the network, the baseline, the closed form
    graphs = {k: kinds.get(k).graph for k in kinds.names()}
    assert len(set(graphs.values())) == 3 and {kinds.get(k).file for k in graphs} == {"net.onnx", "svm.onnx", "lda.onnx"}
    assert kinds.fit_order([kinds.NETWORK]) == ["svm", "lda", "net"]  # what the network starts from, first
    with pytest.raises(kinds.UsageError, match=r"^model must be one of net, svm, lda, got 'knn'$"):
        kinds.get("knn")


def test_the_core_never_imports_the_training_side():
    """Only the CLI's torch verbs (train, export, compare's training: sonicskin/cli/train.py, loaded when they run)
    reach training/; the network's fit comes from the sonicskin.kinds entry point."""
    allowed = {"sonicskin/cli/train.py"}
    for p in (ROOT / "sonicskin").rglob("*.py"):
        rel = str(p.relative_to(ROOT))
        for node in ast.walk(ast.parse(p.read_text())):
            mods = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                    [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            bad = [m for m in mods if m.startswith(("sonicskin.training", "sonicskin.export", "sonicskin.models"))]
            assert not bad or rel in allowed, f"{rel} imports {bad}"
