"""``canopyblocks run``: the whole chain, as named stages.

Photons: :mod:`.run` (``run_chain``: simulate or read photons -> block heights -> PDAL
reference rasters -> validation against the corridor maximum and the footprint-matched
reference -> one terrain per block and one table of facts (:mod:`.facts`) -> figures
(:mod:`.figures`) -> the HTML report (:mod:`.photon_report` from :mod:`.report`'s parts and
:mod:`.glossary`)).  Waveforms: :mod:`.waveforms` (GEDI L1B, its report parts in
:mod:`.waveform_report`) and :mod:`.flash_dual` (ESFL cubes, dual-wavelength pairs).
:mod:`.result` is what every branch returns; :mod:`.tiles` the airborne tiles' CRS and datum.
"""

from __future__ import annotations

from .result import ChainResult
from .run import run_chain

__all__ = ["ChainResult", "run_chain"]
