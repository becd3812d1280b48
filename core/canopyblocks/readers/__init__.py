"""canopyblocks.readers (filled in by its issue)."""
