"""Bring recordings from other rigs into the dataset format, so they train and compare like
simulated data.

``import_wav``: a folder of WAV recordings (one continuous recording per file = one session),
the transmitted sweep (a WAV of one period, any sweep; or a linear chirp's parameters), any
sample rate, and a label CSV of touch intervals::

    file,start_s,end_s,location,x_cm,y_cm,force_n,moving,subject
    run1.wav,3.2,5.9,7,8.4,1.2,3.5,0,0

Chirps starting inside an interval carry its label; the others are no-touch.  ``force_n`` may
be empty (no sensor), ``moving`` marks robot motion (use ``location`` -1 for a moving, hands-off
interval).

``import_spectra``: a table of precomputed channel magnitudes with labels (``.npz`` with arrays
``freqs_hz`` (F,), ``magnitude_db`` (n, F), ``location`` and ``session``, optional ``x_cm``,
``y_cm``, ``force_n``, ``moving``, ``subject``), e.g. from another group's pipeline.  The rig is
derived from the frequency axis (bin spacing = fs / samples per frame); each row becomes one
received chirp of that rig with exactly that magnitude response (zero phase), so every tool of
this package runs on it unchanged.  Levels are normalised (the gain is stored in
``dataset.json``, ``source.gain_db``): no dB offset to choose.

Location labels (both importers) may be integers (kept as location ids), numbers such as
positions in cm (``1.5``, ``2.0``) or names (``"wrist"``); numbers and names become ids
0..K-1 in sorted order.  The mapping is printed and stored in ``dataset.json``
(``source.labels``).  Coordinates come from ``x_cm``/``y_cm``; without them a numeric label is
taken as the position in cm along x, and names are placed 1 cm apart.  A negative number, NaN,
an empty cell or ``none``/``no-touch``/``rest`` means no touch.

Writing is all or nothing: a new dataset is built in a hidden folder beside ``out`` and moved
into place when complete; ``mode="resume"`` keeps the sessions already imported and adds the
rest; ``mode="overwrite"`` replaces ``out`` only once the new import succeeded.

One module each: :mod:`.wav`, :mod:`.spectra`, the label layout both use :mod:`.labels`, and what they share
(the error type, writing all or nothing) :mod:`._common`.
"""

from __future__ import annotations

from ._common import ImportDataError
from .labels import label_layout
from .spectra import STANDARD_RATES_HZ, import_spectra, rig_from_axis
from .wav import import_wav, sweep_rig

__all__ = ["import_wav", "import_spectra", "sweep_rig", "rig_from_axis", "label_layout", "STANDARD_RATES_HZ",
           "ImportDataError"]
