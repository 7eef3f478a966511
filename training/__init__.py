"""Lightning training of the networks in ``models``: ``sonicskin train --config configs/train/<name>.yaml``.

Reproducibility (issue 27.3): a given seed trains bit-identical weights on one machine with one thread count
(``sonicskin --threads``; :func:`training.quick.fit_net` and the Lightning configs' ``deterministic: true`` switch torch
to its deterministic algorithms).  MKL, torch's BLAS on x86, may pick code paths by the memory alignment of its inputs,
which changes from run to run; ``MKL_CBWR=AUTO,STRICT`` (set here unless the environment sets it, before torch's first
BLAS call) asks it for run-to-run reproducible results.  Not reproducible: other thread counts, other CPUs (another
instruction set), other torch/MKL versions; there the same seed can give slightly different weights, and a selection
between candidates within a validation press of each other (``training.quick.choose_layer``) can go the other way.
"""

import os

os.environ.setdefault("MKL_CBWR", "AUTO,STRICT")
