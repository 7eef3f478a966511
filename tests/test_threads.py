"""One thread setting (issue 20): --threads / SONICSKIN_THREADS reach BLAS/OpenMP, scipy.fft and child processes."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
from cli_helpers import assert_one_line_error, run

from sonicskin import threads


def test_default_is_half_the_cores_at_most_four(monkeypatch):
    monkeypatch.delenv(threads.ENV, raising=False)
    monkeypatch.setattr(threads, "_configured", None)
    n = len(os.sched_getaffinity(0))
    assert threads.get() == max(1, min(4, n // 2)) == threads.fft_workers()
    monkeypatch.setenv(threads.ENV, "3")
    assert threads.get() == 3


def test_bad_settings_are_one_line(capsys, monkeypatch):
    code, _, err = run(capsys, ["info", "--threads", "0"])
    assert "--threads must be a whole number of threads from 1 to 1024, got '0'" in assert_one_line_error(code, err, "info")
    monkeypatch.setenv(threads.ENV, "many")
    monkeypatch.setattr(threads, "_configured", None)
    code, _, err = run(capsys, ["info"])
    assert f"{threads.ENV} must be a whole number" in assert_one_line_error(code, err, "info")


def test_configure_limits_the_pools_and_the_children():
    """In a fresh process: BLAS/OpenMP pools, scipy.fft's workers and a child's environment all follow the setting."""
    code = ("import os, numpy, scipy.fft; from threadpoolctl import threadpool_info; from sonicskin import threads; "
            "n = threads.configure(2); assert threads.fft_workers() == 2; "
            "assert all(p['num_threads'] <= 2 for p in threadpool_info()), threadpool_info(); "
            "assert os.environ['OMP_NUM_THREADS'] == '2' == os.environ['SONICSKIN_THREADS']; print(n)")
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_NUM_THREADS", threads.ENV)}
    r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert r.returncode == 0 and r.stdout.strip() == "2", r.stderr


def test_torch_follows_the_setting():
    pytest.importorskip("torch")
    code = ("import torch; from sonicskin import threads; threads.configure(1); from sonicskin.training.quick import fit_net; "
            "threads.apply_torch(); print(torch.get_num_threads())")
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_NUM_THREADS", threads.ENV)}
    r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert r.returncode == 0 and r.stdout.strip() == "1", r.stderr
