"""Bring recordings from other rigs into the dataset format: :func:`import_wav` and :func:`import_spectra`.

Writing is all or nothing (:mod:`._common`).  The formats and options: docs/importers.md."""

from __future__ import annotations

from ._common import ImportDataError
from .labels import label_layout
from .spectra import STANDARD_RATES_HZ, import_spectra, rig_from_axis
from .wav import import_wav, sweep_rig

__all__ = ["import_wav", "import_spectra", "sweep_rig", "rig_from_axis", "label_layout", "STANDARD_RATES_HZ", "ImportDataError"]
