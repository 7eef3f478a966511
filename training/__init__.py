"""Lightning training of the networks in ``models``: ``sonicskin train --config configs/train/<name>.yaml``.

Reproducibility: a given seed trains bit-identical weights on one machine with one thread count (deterministic torch
algorithms; ``MKL_CBWR=AUTO,STRICT``, set here unless the environment sets it, before torch's first BLAS call, so MKL
does not pick code paths by memory alignment).  Other thread counts, CPUs or torch/MKL versions can give slightly
different weights.
"""

import os

os.environ.setdefault("MKL_CBWR", "AUTO,STRICT")
