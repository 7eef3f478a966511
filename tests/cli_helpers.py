"""Helpers of the CLI tests: a small rig (1024-sample chirps, 250 usable bins: fewer than the default
gamma), a tiny 3-marker scenario, and in-process runs of ``sonicskin`` (fixture ``cli_files`` in conftest)."""

from __future__ import annotations

SMALL_RIG = """\
name: small
fs_hz: 192000
f_lo_hz: 20000
f_hi_hz: 80000
n_chirp: 1024
pwm_hz: [30000, 60000]
pwm_halfwidth_hz: 3250
amplitude: 0.5
"""

TINY_SCENARIO = """\
name: tiny
material: abs
geometry: {kind: plate, width_cm: 20.0, length_cm: 25.0}
tx_cm: [4.0, 2.5]
rx_cm: [9.0, 22.5]
layout: {kind: grid, nx: 3, ny: 1, spacing_cm: 1.2, x0_cm: 9.4, y0_cm: 12.5}
sessions: 3
repeats: 1
touch_s: 0.5
gap_s: 0.2
calibration_s: 3.5
moving_s: 0.0
subjects: [0]
motion: {enabled: false}
seed: 4
"""


def run(capsys, argv: list[str]) -> tuple[int, str, str]:
    """``sonicskin argv`` in-process: (exit code, stdout, stderr)."""
    from sonicskin.cli import main

    capsys.readouterr()
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def assert_one_line_error(code: int, err: str, verb: str | None = None) -> str:
    """Exit code 2 and exactly one message line (no traceback); returns the line."""
    lines = [ln for ln in err.splitlines() if ln.strip() and not ln.startswith("sonicskin: warning:")
             and not ln.lstrip().startswith("features:")]
    assert code == 2, err
    assert "Traceback" not in err, err
    assert len(lines) == 1, err
    assert lines[0].startswith(f"sonicskin {verb}: error: " if verb else "sonicskin"), lines[0]
    return lines[0]


def refusals(table):
    """``(argv, message)`` cases as pytest parameters named by their argv."""
    import pytest

    return [pytest.param(argv, message, id=" ".join(map(str, argv))) for argv, message in table]


def refusal(capsys, argv) -> str:
    """The one line ``sonicskin argv`` refuses with (exit 2, no traceback; :func:`assert_one_line_error`), after its
    ``sonicskin <verb>: error: ``."""
    code, _, err = run(capsys, argv)
    verb = str(argv[0])
    return assert_one_line_error(code, err, verb).removeprefix(f"sonicskin {verb}: error: ")


def session_audio(ds, session: str):
    """A simulated session's whole recording (its FLAC parts joined), float32."""
    import numpy as np
    import soundfile as sf

    return np.concatenate([sf.read(ds.root / session / f"part-{p:05d}.flac", dtype="float32")[0] for p in ds.parts(session)])


def press_rows(ds, session: str, tail=("2.5",)) -> list[list[str]]:
    """One label-CSV row per press of a simulated session, as another lab writes them: ``<session>.wav``, the interval
    2 ms around the press's chirps, the location, its x/y in cm, then ``tail`` (force_n, ...)."""
    import numpy as np

    _, lab = ds.read_session(session)
    rows = []
    for v in ds.layout.ids:
        k = np.flatnonzero(lab["location"] == v)
        x, y = ds.layout.coords(np.array([v]))[0]
        rows.append([f"{session}.wav", f"{lab['t_s'][k[0]] - 0.002:.6f}", f"{lab['t_s'][k[-1]] + 0.002:.6f}", str(v),
                     f"{x:g}", f"{y:g}", *tail])
    return rows


def write_recordings(ds, folder, tail=("2.5",)) -> list[list[str]]:
    """Every session of a simulated dataset as a float WAV in ``folder`` (made here); returns their press rows
    (:func:`press_rows`)."""
    from pathlib import Path

    import soundfile as sf

    Path(folder).mkdir()
    rows = []
    for s in ds.sessions:
        sf.write(Path(folder) / f"{s}.wav", session_audio(ds, s), int(ds.rig.fs_hz), subtype="FLOAT")
        rows += press_rows(ds, s, tail)
    return rows


def reseal(session_dir) -> None:
    """Recompute a session's manifest hashes after a test deliberately rewrote its parts (a different
    recording, not damage): the reader otherwise refuses the edited files."""
    import hashlib
    import json
    from pathlib import Path

    d = Path(session_dir)
    info = json.loads((d / "session.json").read_text())
    for e in info["parts"]:
        for ext in ("flac", "csv"):
            e[f"{ext}_sha256"] = hashlib.sha256((d / f"{e['part']}.{ext}").read_bytes()).hexdigest()
    (d / "session.json").write_text(json.dumps(info))


def load_tool(name: str):
    """A script of the repository's tools/ folder (not a package) as a module, e.g. ``load_tool("readme")``."""
    import importlib.util
    import sys
    from pathlib import Path

    spec = importlib.util.spec_from_file_location(f"sonicskin_{name}_tool", Path(__file__).resolve().parents[1] / "tools" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod
