"""Every benchmark script imports: each names only what the package has (a benchmark that imported a removed module
stayed broken for a round, cited as evidence in the code)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

BENCH = sorted((Path(__file__).resolve().parents[1] / "benchmarks").glob("*.py"))


@pytest.mark.parametrize("path", BENCH, ids=[p.stem for p in BENCH])
def test_benchmark_imports(path, monkeypatch):
    pytest.importorskip("torch")
    monkeypatch.syspath_prepend(str(path.parent))  # as `python benchmarks/x.py` runs it: its siblings import
    spec = importlib.util.spec_from_file_location(f"bench_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)  # its module level only: every benchmark runs from `if __name__ == "__main__"`
    assert callable(getattr(module, "main", None)), f"{path.name} has no main()"
