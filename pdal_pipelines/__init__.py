"""PDAL JSON pipelines shipped with canopyblocks (see README.md in this folder)."""
