"""Bring recordings from other rigs into the dataset format, so they train and compare like simulated data.

:func:`import_wav`: a folder of WAV recordings (one session each), the transmitted sweep (a WAV of one period, or a
linear chirp's parameters) and a label CSV of touch intervals; :func:`import_spectra`: a ``.npz`` table of channel
magnitudes with labels, each row one received chirp of a rig derived from the frequency axis.  Location labels may
be ids, numbers (cm) or names (:mod:`.labels`).  Writing is all or nothing (:mod:`._common`).  The formats and
options: docs/importers.md.
"""

from __future__ import annotations

from ._common import ImportDataError
from .labels import label_layout
from .spectra import STANDARD_RATES_HZ, import_spectra, rig_from_axis
from .wav import import_wav, sweep_rig

__all__ = ["import_wav", "import_spectra", "sweep_rig", "rig_from_axis", "label_layout", "STANDARD_RATES_HZ",
           "ImportDataError"]
