"""canopyblocks.validation (filled in by its issue)."""
