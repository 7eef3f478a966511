"""Hostile inputs found by probing the artifact, training and live verbs by hand (notes/hostart-probes.md):
each case failed (a traceback or a silently wrong result) before its fix and must now be one clear line.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from cli_helpers import assert_one_line_error, run

from sonicskin.schema import artifact_digest


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def _edit_resealed(art: Path, edit) -> None:
    """Edit ``skin.json`` and recompute its digest with the package's own function, as a careful tamperer would."""
    meta = json.loads((art / "skin.json").read_text())
    edit(meta)
    meta["digest"] = artifact_digest(meta)
    (art / "skin.json").write_text(json.dumps(meta, indent=1))


# -- skin.json's selection report: free-form before, read by compare --artifact ------------------------------------
SELECTION_EDITS = [
    ("svm-a-string", lambda s: s.__setitem__("svm", "x"), r"selection\.svm must be a JSON object, got str"),
    ("params-missing", lambda s: s["svm"].pop("params"),
     r"selection is not the report model selection writes \(reading it fails with KeyError 'params'\)"),
    ("accuracy-a-string", lambda s: s["svm"]["estimate"].__setitem__("accuracy", "high"),
     r"selection is not the report model selection writes \(reading it fails with ValueError: Unknown format code"),
]


@pytest.mark.parametrize("name, edit, pattern", SELECTION_EDITS, ids=[c[0] for c in SELECTION_EDITS])
def test_a_broken_selection_report_is_one_line(cli_files, tmp_path, capsys, name, edit, pattern):
    """``compare --artifact`` prints the artifact's selection report; a resealed skin.json whose report is not
    what model selection writes ended in an AttributeError/KeyError traceback there."""
    import re

    art = _copy(cli_files["artifact"], tmp_path / "art")
    _edit_resealed(art, lambda m: edit(m["selection"]))
    code, _, err = run(capsys, ["compare", "--data", cli_files["data"], "--artifact", art, "--test", "s002",
                                "--out", tmp_path / "rep"])
    line = assert_one_line_error(code, err, "compare")
    assert re.search(rf"{re.escape(str(art / 'skin.json'))}: {pattern}", line), line
    assert line.endswith("; export the artifact again (`sonicskin export --run DIR` or `sonicskin fit-svm`)"), line
