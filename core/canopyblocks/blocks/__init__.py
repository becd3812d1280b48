"""canopyblocks.blocks (filled in by its issue)."""
