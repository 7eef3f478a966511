"""The suite's reliability (issue 27.2-27.4): `make test` runs both of its steps, no test bounds wall-clock time,
network training is bit-reproducible for a seed, and model selection breaks ties in a fixed order."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]


# -- 27.4: make test runs its serial step even when the parallel one failed -------------------------------------------------
@pytest.mark.parametrize("parallel, serial", [(0, 0), (1, 0), (0, 1), (1, 1)])
def test_make_test_runs_both_steps_and_fails_if_either_failed(tmp_path, parallel, serial):
    if shutil.which("make") is None:
        pytest.skip("make is not installed")
    venv = tmp_path / "venv"
    (venv / "bin").mkdir(parents=True)
    py = venv / "bin" / "python"  # a stand-in for pytest: records its arguments, exits as told
    py.write_text(f'#!/bin/sh\necho "$*" >> {tmp_path / "calls"}\ncase "$*" in *"not serial"*) exit {parallel};; '
                  f'*) exit {serial};; esac\n')
    py.chmod(0o755)
    (venv / ".installed").touch()
    shutil.copy(REPO / "pyproject.toml", tmp_path)
    shutil.copy(REPO / "constraints.txt", tmp_path)
    os.utime(venv / ".installed")  # newer than pyproject.toml and constraints.txt: `install` has nothing to do
    r = subprocess.run(["make", "-s", "-f", str(REPO / "Makefile"), "test", f"VENV={venv}"], cwd=tmp_path, capture_output=True,
                       text=True)
    calls = (tmp_path / "calls").read_text().splitlines()
    assert calls == ["-m pytest -q -n 2 --dist loadfile -m not serial", "-m pytest -q -m serial"]  # both, in order
    assert (r.returncode == 0) == (parallel == 0 and serial == 0), r.stderr
    if parallel or serial:
        assert f"make test: failed (parallel step exit {parallel}, serial step exit {serial})" in r.stderr


# -- 27.2: no test bounds wall-clock time ---------------------------------------------------------------------------------
CLOCK = re.compile(r"(perf_counter|monotonic|time\.time)\(\)[^<>]*<|\b\w*(_ms|p99|p50|median)\w*\s*<\s*\d")


def test_no_test_asserts_a_wall_clock_bound():
    """test_bench_models asserted a p99 below 21.3 ms and measured 33.2 ms at load 5: timings are printed by benchmarks/,
    never bounded in a test.  Exempt: lines saying why the bound is not about speed ("not a speed bound")."""
    hits = []
    for p in sorted((REPO / "tests").glob("test_*.py")):
        if p.name == Path(__file__).name:
            continue
        for n, line in enumerate(p.read_text().splitlines(), 1):
            if "assert" in line and CLOCK.search(line) and "not a speed bound" not in line and "stream_s" not in line:
                hits.append(f"{p.name}:{n}: {line.strip()}")
    assert not hits, "\n".join(hits)


def test_the_clock_scanner_sees_the_old_bounds():
    for line in ("assert time.perf_counter() - t0 < 2.0", "assert 1.0 <= time.perf_counter() - t0 < 2.5",
                 "assert 0 < path_med <= path_p99 < 21.3", "assert time.monotonic() < deadline"):
        assert CLOCK.search(line), line


# -- 27.3: bit-reproducible training and fixed-order ties ----------------------------------------------------------------
TRAIN = """
import hashlib, sys
sys.path.insert(0, {tests!r})
from test_net import _toy
from sonicskin.training.quick import fit_net
X, cls, force = _toy()
pred = fit_net(X, cls, force, n_locations=4, epochs=3, seed=7, kernel_lr=1e-3)
print(hashlib.sha256(b"".join(v.numpy().tobytes() for v in pred.model.state_dict().values())).hexdigest())
"""


def test_network_training_is_bit_reproducible_across_processes():
    """The demo printed `fine-tuned kernel 94%` and `93%` on reruns: a seed must give the same weights every run."""
    pytest.importorskip("torch")
    code = TRAIN.format(tests=str(REPO / "tests"))
    digests = []
    for hashseed in ("1", "2"):  # another hash seed: another set/dict iteration order of strings
        env = {**os.environ, "PYTHONHASHSEED": hashseed, "SONICSKIN_THREADS": "1"}
        r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=REPO)
        assert r.returncode == 0, r.stderr[-2000:]
        digests.append(r.stdout.split()[-1])
    assert digests[0] == digests[1] and len(digests[0]) == 64


def test_choose_layer_breaks_ties_at_the_printed_percent_in_a_fixed_order(monkeypatch):
    """A candidate ahead by less than the printed precision does not win: the line would show a tie, which goes to the
    closed form (the first in LAYERS' order)."""
    pytest.importorskip("torch")
    from types import SimpleNamespace

    from sonicskin.training import quick

    from sonicskin.kinds import Fitted

    n, K = 1000, 4
    cls = np.arange(n) % K
    data = SimpleNamespace(X=np.zeros((n, 3), np.float32), cls=cls, force=np.zeros(n), n_locations=K)
    acc = {}

    def fake_fit(X_, cls_, force_, *, n_locations, seed=0, layer="mlp", **kw):
        right = int(round(acc["MLP, every bin"] * n))

        def predict(Xq):
            lg = np.zeros((len(Xq), K + 1), np.float32)
            lg[np.arange(len(Xq)), cls] = 1.0  # every chirp right ...
            lg[right:, :K] = np.roll(lg[right:, :K], 1, axis=1)  # ... but the last n - right
            return lg, np.zeros((len(Xq), K), np.float32)

        predict.model = None
        return predict

    monkeypatch.setattr(quick, "fit_net", fake_fit)
    rows = np.ones(n, bool)
    for scores, want in (({"MLP, every bin": 0.944, "LDA (closed form)": 0.934}, "MLP, every bin"),
                         ({"MLP, every bin": 0.944, "LDA (closed form)": 0.936}, "LDA (closed form)")):
        acc.update(scores)
        lda = Fitted(None, {}, 3, {"lda": {"status": "validated", "accuracy": scores["LDA (closed form)"]}})
        out = quick.choose_layer(data, folds=[(rows, rows, None)], how="test", fitted={"lda": lda})
        assert out["location_layer"] == want, out["layer_how"]
    assert out["layer_how"] == "test: LDA (closed form) 94%, MLP, every bin 94%"
