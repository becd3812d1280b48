"""Full-waveform lidar: GEDI L2A-style processing, Gaussian decomposition, cover,
the seed-003 terrain filter, flash-array and dual-wavelength methods (DESIGN section 4).

Every step works on a :class:`~canopyblocks.waveforms.batch.WaveformBatch` (shots x
samples), vectorised over shots.
"""

from __future__ import annotations

from .batch import WaveformBatch

__all__ = ["WaveformBatch"]
