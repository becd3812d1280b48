"""canopyblocks.workflows: from files to layers, one module per workflow.

Each module is the one place its command and its QGIS algorithm call:
``blocks`` (photon file -> block layers; ``blocks_tracks`` reads and blocks each track, in
this process or in worker processes; ``blocks_granules`` many granules into one table), ``segments`` (photon file -> ATL08-style segments),
``waveforms`` (GEDI L1B -> footprint layer; ``waveforms_beams`` runs beams in workers),
``chain`` (photons -> blocks -> reference -> validation -> report; ``chain_waveforms`` is its
waveform branch; ``chain_figures`` the estimator sets and figures of a photon run,
``chain_photon_report`` its HTML report built from ``chain_report``'s parts,
``chain_waveform_report`` the GEDI report's parts, ``chain_result`` what both return,
``chain_tiles`` the airborne tiles' CRS and datum) and
``batch`` (many granules against many airborne tiles); ``validate``, ``coregister`` and
``calibrate`` (block or footprint files against the reference). ``backends`` is the one
process pool (serial, processes, Dask) they share.
"""
