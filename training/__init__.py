"""Lightning training of the networks in ``models``: ``sonicskin train --config configs/train/<name>.yaml``.

A given seed trains bit-identical weights on one machine with one thread count (deterministic torch algorithms;
``MKL_CBWR=AUTO,STRICT``, set here before torch's first BLAS call unless the environment sets it)."""

import os

os.environ.setdefault("MKL_CBWR", "AUTO,STRICT")
