"""One module per Processing algorithm; ids are stable (``canopyblocks:<id>``)."""
