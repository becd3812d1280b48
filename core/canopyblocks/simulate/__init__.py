"""canopyblocks.simulate (filled in by its issue)."""
