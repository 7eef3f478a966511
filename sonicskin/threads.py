"""One setting for the threads sonicskin's numerical work uses (torch, scipy.fft, BLAS/OpenMP), so training and the
live loop do not fight over every core: :func:`configure` (``--threads N``), else ``SONICSKIN_THREADS``, else half
the cores (1-4).  The live loop's onnxruntime session uses one thread whatever this says."""

from __future__ import annotations

import os
import sys

__all__ = ["ENV", "default_threads", "get", "configure", "fft_workers", "apply_torch"]

ENV = "SONICSKIN_THREADS"
_configured: int | None = None


def default_threads() -> int:
    """Half the cores the process may run on, at least 1 and at most 4."""
    try:
        n = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        n = os.cpu_count() or 1
    return max(1, min(4, n // 2))


def _parse(value: str, where: str) -> int:
    try:
        n = int(value)
    except ValueError:
        n = 0
    if n < 1 or n > 1024:
        raise ValueError(f"{where} must be a whole number of threads from 1 to 1024, got {value!r} "
                         f"(unset it for the default, {default_threads()} on this computer)")
    return n


def get() -> int:
    """The thread count in force (see the module's docstring for where it comes from)."""
    if _configured is not None:
        return _configured
    env = os.environ.get(ENV, "").strip()
    return _parse(env, ENV) if env else default_threads()


def fft_workers() -> int:
    """``workers`` for :mod:`scipy.fft` calls."""
    return get()


def configure(n: int | str | None = None) -> int:
    """Fix the thread count for this process and the ones it starts (BLAS/OpenMP, torch, ``*_NUM_THREADS``); returns it."""
    global _configured
    n = get() if n is None else _parse(str(n), "--threads")
    _configured = n
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", ENV):
        os.environ[var] = str(n)
    try:
        from threadpoolctl import threadpool_limits

        threadpool_limits(limits=n)
    except ImportError:  # scikit-learn depends on threadpoolctl; without it the env variables still act on children
        pass
    if "torch" in sys.modules:
        apply_torch()
    return n


def apply_torch() -> None:
    """Set torch's intra-op thread count to :func:`get` (call after importing torch)."""
    import torch

    n = get()
    if torch.get_num_threads() != n:
        torch.set_num_threads(n)
