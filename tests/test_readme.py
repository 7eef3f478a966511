"""The command blocks of README.md and the manual's pages (docs/), pasted in order on a fresh folder, run; their
deterministic outputs are this commit's; every page is listed and every relative link lands.

The blocks and their markers are described in tools/readme.py (`make docs` writes the outputs).
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from cli_helpers import load_tool

ROOT = Path(__file__).resolve().parents[1]


readme = load_tool("readme")

GOOD = """\
Intro.

<!-- run: one exact -->
```bash
echo "took 1.5 s"   # a comment the output does not show
printf 'a  \\nb\\r\\n'
```
<!-- small: one
echo small
-->

<!-- output: one -->
```text
$ echo "took 9.9 s"
old
```

<!-- norun: needs hardware -->
```bash
sonicskin devices
```

<!-- output: two -->

<!-- run: two -->
```bash
echo hello > f.txt && cat f.txt
```
"""

PAGE = """\
# A page

<!-- run: three -->
```python
print(open("f.txt").read().strip(), "from python")
```

<!-- output: three -->
"""


def test_markers_are_parsed_and_every_shell_block_is_marked():
    r = readme.parse(GOOD)
    assert [b.name for b in r.blocks] == ["one", "two"]
    one, two = r.blocks
    assert one.exact and not two.exact and one.small == "echo small\n" and two.small is None
    assert one.script.startswith('echo "took 1.5 s"') and r.norun == [("README.md", 18, "needs hardware")]
    assert [(o.name, o.text) for o in r.outputs] == [("one", '$ echo "took 9.9 s"\nold'), ("two", None)]
    assert readme.shown(r) == {"one", "two"}
    for bad, msg in [
        ("```bash\nls\n```\n", "README.md:1: a bash block without"),
        ("```python\nprint(1)\n```\n", "README.md:1: a python block without"),
        ("<!-- run: a -->\ntext\n", "must stand right before a ```bash or ```python block"),
        ("<!-- run: a colour=red -->\n```bash\nls\n```\n", "unknown run attribute(s) ['colour']"),
        ("<!-- output: b -->\n", "output of 'b', but no `<!-- run: b -->` block"),
        ("<!-- small: c\nls\n-->\n", "small variant of 'c'"),
        ("<!-- small: c\nls\n", "is not closed by a line `-->`"),
        ("<!-- norun: -->\n```bash\nls\n```\n", "needs a reason"),
        ("<!-- figure: x.png from=a.png -->\n", "a PNG under docs/"),
        ("```bash\nls\n", "README.md:1: unclosed code block"),
    ]:
        with pytest.raises(readme.ReadmeError, match=re.escape(msg)):
            readme.parse(bad)


def test_pages_run_after_the_readme_and_share_its_block_names():
    r = readme.parse({"README.md": GOOD, "docs/page.md": PAGE})
    assert [(b.name, b.where, b.lang) for b in r.blocks] == [
        ("one", "README.md:3", "bash"), ("two", "README.md:25", "bash"), ("three", "docs/page.md:3", "python")]
    assert [(o.name, o.doc) for o in r.outputs][-1] == ("three", "docs/page.md")
    # a name is one block in all documents; markers in a page are reported with the page's name and line
    with pytest.raises(readme.ReadmeError, match=re.escape("docs/page.md:3: a second run block named 'one'")):
        readme.parse({"README.md": GOOD, "docs/page.md": PAGE.replace("run: three", "run: one")})
    with pytest.raises(readme.ReadmeError, match=re.escape("docs/page.md:8: output of 'four', but no")):
        readme.parse({"README.md": GOOD, "docs/page.md": PAGE.replace("output: three", "output: four")})


def test_commands_are_echoed_without_comments_and_continuations_stay_one_command():
    script = 'sonicskin a --x 1 \\\n    --y "a # b"   # why\n\n# alone\nmake demo   # c\n'
    assert readme.commands(script) == ['sonicskin a --x 1 \\\n    --y "a # b"   # why', "make demo   # c"]
    assert readme._shown(readme.commands(script)[0]) == 'sonicskin a --x 1 \\\n    --y "a # b"'
    assert readme._shown("make demo   # c") == "make demo"


def test_timings_are_masked_and_progress_bars_dropped():
    assert (readme.mask("in 53.7 s: 107 chirps/s, 216 us, 9.7 min; 3 sessions, 0.04 cm")
            == "in # s: # chirps/s, # us, # min; 3 sessions, 0.04 cm")
    raw = "features:   0%|   | 0/3 [00:00<?, ?session/s]\rfeatures: 100%|###| 3/3 [00:00<00:00, 35.8session/s]\nkept  \nx\rdone"
    assert readme.clean(raw) == "kept\ndone"


def test_a_small_manual_runs_renders_into_each_document_and_detects_stale_output(tmp_path):
    r = readme.parse({"README.md": GOOD, "docs/page.md": PAGE})
    results = readme.run_all(small=False, check=False, man=r, keep=tmp_path / "run")
    assert [x.output for x in results] == ['$ echo "took 1.5 s"\ntook 1.5 s\n$ printf \'a  \\nb\\r\\n\'\na\nb\n',
                                           "$ echo hello > f.txt && cat f.txt\nhello\n", "hello from python\n"]
    texts = readme.render(r, results)
    # each output lands in the document that holds its marker; the rendered documents parse again, the exact block
    # matches, the non-exact ones carry where they ran
    assert "```text\nhello from python\n```\n" + readme.STAMP_PREFIX in texts["docs/page.md"]
    assert "hello from python" not in texts["README.md"]
    again = readme.parse(texts)
    assert [o.text for o in again.outputs][0] == '$ echo "took 1.5 s"\ntook 1.5 s\n$ printf \'a  \\nb\\r\\n\'\na\nb'
    text = texts["README.md"]
    assert readme.STAMP_PREFIX + " on " in text and text.count(readme.STAMP_PREFIX) == 1 and "cores, load" in text
    assert readme.render(again, results) == texts  # idempotent: nothing accumulates
    readme.compare_exact(results[0], again)  # timings differ only by the masked number
    with pytest.raises(readme.ReadmeError, match=r"README.md:12: the output of 'one' is stale; run `make docs`"):
        readme.compare_exact(results[0], r)
    # the small variant replaces the block; a failing command names the block, its document and line, and its last lines
    assert readme.run_block(r.blocks[0], tmp_path / "run", small=True).output == "$ echo small\nsmall\n"
    bad = readme.Block("broken", "echo before\nfalse\necho after\n", 7, doc="docs/page.md")
    with pytest.raises(readme.ReadmeError, match=r"(?s)docs/page.md:7: block 'broken' \(as written\) failed: exit code 1.*before"):
        readme.run_block(bad, tmp_path / "run", small=False)
    bad = readme.Block("broken", "print('before')\nraise SystemExit(3)\n", 9, doc="docs/page.md", lang="python")
    with pytest.raises(readme.ReadmeError, match=r"(?s)docs/page.md:9: block 'broken' \(as written\) failed: exit code 3.*before"):
        readme.run_block(bad, tmp_path / "run", small=False)


def _slug(heading: str) -> str:
    """GitHub's anchor of a heading."""
    return re.sub(r"\s", "-", re.sub(r"[^\w\- ]", "", heading.strip().lower()))


def _anchors(text: str) -> set[str]:
    out, fence = set(), None
    for ln in text.split("\n"):
        m = re.match(r"^(```+|~~~+)", ln)
        if m and fence is None:
            fence = m.group(1)
        elif fence and ln.startswith(fence):
            fence = None
        elif fence is None and re.match(r"^#{1,6} ", ln):
            out.add(_slug(ln.lstrip("#")))
    return out


def broken_links(doc: str, text: str) -> list[str]:
    """Relative links and images of ``doc`` whose file or heading does not exist."""
    out = []
    for m in re.finditer(r"!?\[[^\]]*\]\(([^)\s]+)\)", text):
        target = m.group(1)
        if re.match(r"^[a-z]+:", target):
            continue
        path, _, anchor = target.partition("#")
        dest = (ROOT / doc).parent / path if path else ROOT / doc
        line = text.count("\n", 0, m.start()) + 1
        if not dest.exists():
            out.append(f"{doc}:{line}: {target}: no such file")
        elif anchor and dest.suffix == ".md" and anchor not in _anchors(dest.read_text() if path else text):
            out.append(f"{doc}:{line}: {target}: no heading #{anchor} in {path or doc}")
    return out


def test_broken_links_are_found():
    text = "[a](docs/history.md) [b](#nowhere) [c](docs/none.md) [d](https://x.org/#y) ![e](docs/probe.png)\n# Here it is\n[f](#here-it-is)"
    assert broken_links("README.md", text) == ["README.md:1: #nowhere: no heading #nowhere in README.md",
                                               "README.md:1: docs/none.md: no such file"]
    assert _slug("`record` then `live`: 3 passes (why)") == "record-then-live-3-passes-why"


def test_the_documents_are_marked_listed_and_linked():
    r = readme.parse(readme.read())
    names = [b.name for b in r.blocks]
    assert {"demo", "api", "spectra", "wav", "learned"} <= set(names)
    assert {b.name for b in r.blocks if b.exact} >= {"spectra", "wav"}
    assert next(b for b in r.blocks if b.name == "api").lang == "python"
    for fig in r.figures:  # committed and small
        assert (ROOT / fig.dest).is_file() and (ROOT / fig.dest).stat().st_size < 300_000, fig.dest
    for o in r.outputs:
        assert o.text, f"{o.doc}:{o.start + 1}: output of {o.name!r} is empty: run `make docs`"
    # every page of docs/ is in the manual's one list (or a record), and the README stays short
    pages = {p.relative_to(ROOT).as_posix() for p in (ROOT / "docs").glob("*.md")}
    assert pages == set(readme.PAGES) | set(readme.RECORDS), "list new pages in PAGES (tools/readme.py)"
    assert len((ROOT / "README.md").read_text().splitlines()) <= 250
    problems = [p for doc in (*readme.DOCS, *readme.RECORDS) for p in broken_links(doc, (ROOT / doc).read_text())]
    assert problems == [], "\n".join(problems)


#: the blocks that train no model: they run in every test (seconds); the others (the demo's training, live, the learned
#: models and the seeds study: minutes) run in `make docs` and `python tools/readme.py --check`
QUICK = ("spectra", "wav", "help", "simulate", "robot-frame")


def test_the_blocks_that_train_nothing_run_in_order_and_exact_outputs_are_this_commits(tmp_path):
    """The marked blocks that train no model, as written or their small variants, in order on one fresh folder: each
    runs, and the exact outputs (the importers') are this commit's."""
    man = readme.parse(readme.read())
    assert set(QUICK) <= {b.name for b in man.blocks} and {b.name for b in man.blocks if b.exact} <= set(QUICK)
    results = readme.run_all(small=True, check=True, only=list(QUICK), keep=tmp_path / "clone")
    assert [x.block.name for x in results] == [b.name for b in man.blocks if b.name in QUICK]
    for path in ("data/lab-b/dataset.json", "data/lab-c/dataset.json", "data/glass/dataset.json"):
        assert (tmp_path / "clone" / path).is_file(), path


def _documented_commands() -> list[tuple[str, list[str]]]:
    """Every ``sonicskin`` command of the marked bash blocks, as written and in their small variants (``make demo``: its
    recipe's commands, with the block's SIM_OPTS/TRAIN_OPTS), as (where, argv after ``sonicskin``)."""
    import shlex

    recipe = (ROOT / "Makefile").read_text().split("\ndemo:")[1].split("\n\n")[0]
    out = []
    for b in readme.parse(readme.read()).blocks:
        for script in (b.script, b.small) if b.lang == "bash" else ():
            for cmd in readme.commands(script or ""):
                argv = shlex.split(readme._shown(cmd).replace("\\\n", " "))
                if argv[:2] == ["make", "demo"]:
                    opts = dict(a.split("=", 1) for a in argv[2:])
                    for ln in recipe.splitlines():
                        if "-m sonicskin" in ln:
                            ln = ln.split("-m sonicskin", 1)[1].replace("$(DATA)", "data").replace("$(REPORTS)", "reports")
                            ln = ln.replace("$(SIM_OPTS)", opts.get("SIM_OPTS", "")).replace("$(TRAIN_OPTS)", opts.get("TRAIN_OPTS", ""))
                            out.append((f"{b.where} make demo", shlex.split(ln)))
                elif argv[0] == "sonicskin":
                    out.append((b.where, argv[1:]))
    return out


def test_every_documented_command_is_one_the_cli_takes():
    """Each command the documents show parses as written: a verb or option renamed or removed fails here at once, not
    in the minutes-long run of the whole manual."""
    from sonicskin.cli import build_parser

    cmds = _documented_commands()
    assert len(cmds) >= 25 and any(w.endswith("make demo") for w, _ in cmds)
    bad = []
    for where, argv in cmds:
        if argv == ["--help"]:
            continue
        try:
            a, extra = build_parser().parse_known_args(argv)
        except SystemExit:
            bad.append(f"{where}: sonicskin {' '.join(argv)}: refused")
            continue
        if extra and not getattr(a, "passthrough", False):
            bad.append(f"{where}: sonicskin {' '.join(argv)}: unrecognized {extra}")
    assert bad == [], "\n".join(bad)
