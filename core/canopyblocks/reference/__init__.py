"""canopyblocks.reference (filled in by its issue)."""
