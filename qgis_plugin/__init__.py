"""canopyblocks QGIS plugin: Processing algorithms over the canopyblocks core library.

The plugin folder holds only the QGIS front-end; the science is the ``canopyblocks``
package, which must be installed into the Python that runs QGIS (see metadata.txt).
"""

from __future__ import annotations

from typing import Any

from .venv_guard import scrub_venv

# before anything imports the core: an activated virtualenv's PyPI wheels must not be seen
scrub_venv()


def classFactory(iface: Any) -> Any:  # noqa: N802 - QGIS plugin entry point name
    """QGIS entry point: return the plugin object."""
    from .plugin import CanopyBlocksPlugin

    return CanopyBlocksPlugin(iface)
