"""Hostile findings of issue 37 on the new surfaces: arm and scenario files whose values are YAML alias bombs, the MCAP
writer's output file, the Alg. 2 reference's clock, and the live view's server.  Each was a hang, a traceback, lost
data or a silently wrong result before its fix, and must now be one clear line (or the right result)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from sonicskin.errors import brief

# A 1 kB YAML value whose repr has 9**9 elements (nine levels of nine aliases of the level below).
BOMB = "[&l0 [x, x, x, x, x, x, x, x, x], " + ", ".join(
    f"&l{k} [" + ", ".join([f"*l{k - 1}"] * 9) + "]" for k in range(1, 9)) + "]"


def _cli(tmp_path: Path, *argv, timeout: float = 120) -> tuple[int, str]:
    """``sonicskin argv`` in a child process (a hang is a failed test, not a stuck suite): (exit code, stderr)."""
    r = subprocess.run([sys.executable, "-m", "sonicskin", *map(str, argv)], cwd=tmp_path, capture_output=True, text=True,
                       timeout=timeout)
    return r.returncode, r.stderr


def test_brief_never_materialises_a_nested_value():
    x = ["x"] * 9
    for _ in range(9):  # the bomb's shape: 9 references to the level below, 9 levels deep
        x = [x] * 9
    s = brief(x)
    assert len(s) <= 100 and s.startswith("[[[") and s.endswith("...")
    assert brief("a" * 10**6).count("a") < 100 and brief("plain") == "'plain'" and brief(2.5) == "2.5"


@pytest.mark.parametrize("where", ["name", "link-name", "link-artifact", "scenario-base", "scenario-material"])
def test_an_alias_bomb_in_an_arm_file_is_one_short_line(tmp_path, where):
    """Every error message embedding a value prints it bounded, and a value of the wrong type is refused before anything
    iterates or converts it (``str()`` of the bomb hung the --links verbs with memory climbing)."""
    v = {k: "BOMB" if k == where else None for k in ("name", "link-name", "link-artifact", "scenario-base", "scenario-material")}
    text = (f"name: {v['name'] or 't'}\nduplex: none\nlinks:\n"
            f"  - name: {v['link-name'] or 'a'}\n    tx: 0\n    rx: 0\n"
            + (f"    artifact: {v['link-artifact']}\n" if v["link-artifact"] else "")
            + f"    scenario: {{base: {v['scenario-base'] or 'stationary'}, material: {v['scenario-material'] or 'cfrp'}}}\n")
    (tmp_path / "arm.yaml").write_text(text.replace("BOMB", BOMB))
    code, err = _cli(tmp_path, "simulate", "--links", "arm.yaml", "--out", "d", "--quiet")
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and "Traceback" not in err and len(lines[0]) < 400, err[:2000]
    assert "[['x', 'x', 'x', 'x', ...]" in lines[0]


def test_an_alias_bomb_as_a_scenario_value_is_one_short_line(tmp_path):
    (tmp_path / "sc.yaml").write_text(f"name: s\nmaterial: {BOMB}\n")
    code, err = _cli(tmp_path, "simulate", "--scenario", "sc.yaml", "--out", "d", "--quiet")
    assert code == 2 and len(err.strip().splitlines()) == 1 and len(err) < 400, err[:2000]
    assert "scenario material must be a string, got [['x', 'x', 'x', 'x', ...]" in err
