"""canopyblocks.workflows: from files to layers, one module per workflow.

Each module is the one place its command and its QGIS algorithm call:
``blocks`` (photon file -> block layers; ``blocks_tracks`` reads and blocks each track, in
this process or in worker processes; ``blocks_granules`` many granules into one table), ``segments`` (photon file -> ATL08-style segments),
``waveforms`` (GEDI L1B -> footprint layer; ``waveforms_beams`` runs beams in workers),
``chain`` (a package of named stages: ``chain.run`` photons -> blocks -> reference ->
validation -> facts -> report; ``chain.waveforms`` and ``chain.flash_dual`` its waveform
branches; ``chain.facts`` the run's one terrain and table of facts, ``chain.figures`` the
estimator sets and figures, ``chain.photon_report`` the HTML report built from
``chain.report``'s parts and ``chain.glossary``, ``chain.waveform_report`` the GEDI report's
parts, ``chain.result`` what every branch returns, ``chain.tiles`` the airborne tiles' CRS
and datum) and
``batch`` (many granules against many airborne tiles); ``validate``, ``coregister`` and
``calibrate`` (block or footprint files against the reference). ``backends`` is the one
process pool (serial, processes, Dask) they share.
"""
