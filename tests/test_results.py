"""The measured results of README.md and the manual are the stored stdout of registered commands (tools/results.py)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from cli_helpers import load_tool

ROOT = Path(__file__).resolve().parents[1]


results = load_tool("results")

INDEX = """\
hello:
  cost: a second
  run: |
    echo "| a | b |"; echo "|---|---|"; echo "| 1 | 2 |"; echo "log line" >&2
plain:
  cost: a second
  format: text
  run: |
    printf 'x 1.5 ms\\n'
broken:
  cost: a second
  run: |
    echo partial; exit 3
"""

README = """\
# r

<!-- result: hello -->
<!-- /result -->

<!-- spec: parameters -->
| k | v |
|---|---|

<!-- result: plain -->
old
<!-- /result -->
"""


@pytest.fixture
def store(tmp_path, monkeypatch):
    (tmp_path / "docs/results").mkdir(parents=True)
    (tmp_path / "docs/results/index.yaml").write_text(INDEX)
    monkeypatch.setattr(results, "STORE", tmp_path / "docs/results")
    monkeypatch.setattr(results, "INDEX", tmp_path / "docs/results/index.yaml")
    return tmp_path


def test_a_run_stores_stdout_with_its_provenance_and_renders(store):
    reg = results.index()
    rec = results.run("hello", reg["hello"], log=lambda s: None)
    assert rec["stdout"] == "| a | b |\n|---|---|\n| 1 | 2 |"  # stderr is not part of the result
    assert len(rec["commit"]) == 40 and rec["run"] == reg["hello"]["run"] and rec["wall_s"] >= 0
    assert json.loads((store / "docs/results/hello.json").read_text()) == rec
    results.run("plain", reg["plain"], log=lambda s: None)
    text = results.render(README)
    assert "| 1 | 2 |\n\n" + results.STAMP_PREFIX + " hello` (commit " in text  # a blank line ends the table
    assert "```text\nx 1.5 ms\n```\n\n" + results.STAMP_PREFIX in text and "\nold\n" not in text
    assert results.render(text) == text  # idempotent
    assert results.problems(text) == []
    # a stale block, a changed command, an unmarked table or text block each fail the check
    assert any("differs from its stored result" in p for p in results.problems(text.replace("| 1 | 2 |", "| 1 | 3 |")))
    (store / "docs/results/index.yaml").write_text(INDEX.replace('echo "| 1 | 2 |"', 'echo "| 1 | 9 |"'))
    assert any("measured by another command" in p for p in results.problems(text))
    (store / "docs/results/index.yaml").write_text(INDEX)
    bad = text + "\n| hand | typed |\n|---|---|\n\n```text\n96.0 %\n```\n\n```\n95 %\n```\n"
    probs = results.problems(bad)
    assert sum("a table that is neither" in p for p in probs) == 1
    assert sum("a text or plain block" in p for p in probs) == 2


def test_a_failing_or_silent_command_stores_nothing(store):
    reg = results.index()
    with pytest.raises(results.ResultError, match=r"broken: the command failed \(exit code 3\); nothing stored"):
        results.run("broken", reg["broken"], log=lambda s: None)
    assert not (store / "docs/results/broken.json").exists()
    with pytest.raises(results.ResultError, match="nothing on stdout"):
        results.run("quiet", {"run": "true", "cost": "0 s"}, log=lambda s: None)


def test_unmeasured_and_unregistered_results_are_named(store):
    assert "not measured yet: `python tools/results.py run hello`" in results.render(README)
    assert any("'hello' was never measured" in p for p in results.problems(README))
    with pytest.raises(results.ResultError, match="'nope' is not registered"):
        results.render("<!-- result: nope -->\n<!-- /result -->\n")
    with pytest.raises(results.ResultError, match="is not closed"):
        results.regions(["<!-- result: hello -->", "x"])
    # CI's own time can only be measured once its commit exists: such a result may be unmeasured
    marked = INDEX.replace("hello:\n  cost: a second", "hello:\n  of_the_commit: true\n  cost: a second")
    (store / "docs/results/index.yaml").write_text(marked)
    assert not any("'hello' was never measured" in p for p in results.problems(README))
    (store / "docs/results/index.yaml").write_text("x:\n  run: echo\n")
    with pytest.raises(results.ResultError, match="needs `run`.*and `cost`"):
        results.index()


def test_results_may_live_in_any_page_once_and_every_page_is_checked(store):
    results.run("hello", results.index()["hello"], log=lambda s: None)
    results.run("plain", results.index()["plain"], log=lambda s: None)
    page = "# p\n\n<!-- result: hello -->\n<!-- /result -->\n"
    texts = {"README.md": results.render(README), "docs/p.md": results.render(page, "docs/p.md")}
    assert "| 1 | 2 |" in texts["docs/p.md"]
    probs = results.problems(texts)
    assert probs == ["docs/p.md:3: result 'hello' is shown twice (also at README.md:3); show it in one place and link there"]
    probs = results.problems({"README.md": texts["README.md"], "docs/p.md": "# p\n\n| typed | by hand |\n|---|---|\n"})
    assert probs == ["docs/p.md:3: a table that is neither a result (<!-- result: NAME -->) nor marked "
                     "<!-- spec: WHY --> (parameters, not measurements)"]
    with pytest.raises(results.ResultError, match=r"docs/p.md:1: result 'x' is not closed"):
        results.regions(["<!-- result: x -->"], "docs/p.md")


def test_every_result_of_the_documents_is_stored_shown_once_as_stored_and_every_table_is_marked():
    """README.md and the manual's pages: each measured table/figure is a stored result of its registered command."""
    problems = results.problems(results.read())
    assert problems == [], "\n".join(problems)
    reg = results.index()
    shown = results.shown()
    assert set(shown) == set(reg), f"registered but in no document: {sorted(set(reg) - set(shown))}"
    for name in reg:  # the commands a result names exist
        for word in reg[name]["run"].split():
            if word.startswith(("benchmarks/", "tools/")):
                assert (ROOT / word).is_file(), f"{name}: {word} does not exist"
