"""The README's command blocks, pasted in order on a fresh folder, run; its deterministic outputs are this commit's.

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


def test_markers_are_parsed_and_every_shell_block_is_marked():
    r = readme.parse(GOOD)
    assert [b.name for b in r.blocks] == ["one", "two"]
    one, two = r.blocks
    assert one.exact and not two.exact and one.small == "echo small\n" and two.small is None
    assert one.script.startswith('echo "took 1.5 s"') and r.norun == [(18, "needs hardware")]
    assert [(o.name, o.text) for o in r.outputs] == [("one", '$ echo "took 9.9 s"\nold'), ("two", None)]
    assert readme.shown(r) == {"one", "two"}
    for bad, msg in [
        ("```bash\nls\n```\n", "a bash block without"),
        ("<!-- run: a -->\ntext\n", "must stand right before a ```bash block"),
        ("<!-- run: a colour=red -->\n```bash\nls\n```\n", "unknown run attribute(s) ['colour']"),
        ("<!-- output: b -->\n", "output of 'b', but no `<!-- run: b -->` block"),
        ("<!-- small: c\nls\n-->\n", "small variant of 'c'"),
        ("<!-- small: c\nls\n", "is not closed by a line `-->`"),
        ("<!-- norun: -->\n```bash\nls\n```\n", "needs a reason"),
        ("<!-- figure: x.png from=a.png -->\n", "a PNG under docs/"),
    ]:
        with pytest.raises(readme.ReadmeError, match=re.escape(msg)):
            readme.parse(bad)


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


def test_a_small_readme_runs_renders_and_detects_stale_output(tmp_path):
    r = readme.parse(GOOD)
    results = readme.run_all(small=False, check=False, readme=r, keep=tmp_path / "run")
    assert [x.output for x in results] == ['$ echo "took 1.5 s"\ntook 1.5 s\n$ printf \'a  \\nb\\r\\n\'\na\nb\n',
                                           "$ echo hello > f.txt && cat f.txt\nhello\n"]
    text = readme.render(r, results)
    # the rendered README parses again, its exact block matches, the non-exact one carries where it ran
    again = readme.parse(text)
    assert [o.text for o in again.outputs][0] == '$ echo "took 1.5 s"\ntook 1.5 s\n$ printf \'a  \\nb\\r\\n\'\na\nb'
    assert readme.STAMP_PREFIX + " on " in text and text.count(readme.STAMP_PREFIX) == 1 and "cores, load" in text
    assert readme.render(again, results) == text  # idempotent: nothing accumulates
    readme.compare_exact(results[0], again)  # timings differ only by the masked number
    with pytest.raises(readme.ReadmeError, match=r"the output of 'one' is stale; run `make docs`"):
        readme.compare_exact(results[0], r)
    # the small variant replaces the block; a failing command names the block and shows its last lines
    assert readme.run_block(r.blocks[0], tmp_path / "run", small=True).output == "$ echo small\nsmall\n"
    bad = readme.Block("broken", "echo before\nfalse\necho after\n", 7)
    with pytest.raises(readme.ReadmeError, match=r"(?s)README.md:7: block 'broken' \(as written\) failed: exit code 1.*before"):
        readme.run_block(bad, tmp_path / "run", small=False)


def test_the_readme_is_marked():
    r = readme.parse(readme.README.read_text())
    names = [b.name for b in r.blocks]
    assert {"demo", "spectra", "wav"} <= set(names)
    assert {b.name for b in r.blocks if b.exact} >= {"spectra", "wav"}
    for fig in r.figures:  # committed and small
        assert (ROOT / fig.dest).is_file() and (ROOT / fig.dest).stat().st_size < 300_000, fig.dest
    for o in r.outputs:
        assert o.text, f"README.md:{o.start + 1}: output of {o.name!r} is empty: run `make docs`"


@pytest.mark.slow
def test_readme_blocks_run_in_order_and_exact_outputs_are_this_commits(tmp_path):
    """Every marked block, small variants where given, in README order on one fresh folder (~2 min on 2 quiet cores)."""
    results = readme.run_all(small=True, check=True, keep=tmp_path / "clone")
    assert [x.block.name for x in results] == [b.name for b in readme.parse(readme.README.read_text()).blocks]
    # the walkthroughs left what the README says they write
    for path in ("reports/moving/report.json", "reports/compare-moving/compare.png", "artifacts/moving/skin.json",
                 "data/lab-b/dataset.json", "artifacts/lab-c/skin.json"):
        assert (tmp_path / "clone" / path).is_file(), path
