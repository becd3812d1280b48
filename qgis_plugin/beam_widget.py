"""The beam box of the photon algorithms: the beams of the chosen file, as a list.

When the photon file changes in the dialog, its beams are read (names, strength and photon
count, from the file's headers only: no photon is read) and offered in an editable list;
typing stays possible (a MABEL channel number or 'most', or a table's track).  Outside the
dialog (``processing.run``, ``qgis_process``, the modeler) the parameter is the same text
as before (``TRACK=gt1r``).
"""

from __future__ import annotations

from typing import Any

__all__ = ["file_beams", "track_widget_metadata"]


def file_beams(path: str) -> list[tuple[str, str]]:
    """``[(label, beam), ...]`` for an ATL03 file (e.g. ``("gt1r - strong, 6809 photons",
    "gt1r")``); empty for anything else or a file that cannot be read."""
    if not path or not path.lower().endswith((".h5", ".hdf5", ".he5")):
        return []
    try:
        from canopyblocks.workflows.inputs import atl03_beams

        beams = atl03_beams(path)
    except Exception:  # noqa: BLE001 - not ATL03 (MABEL, damaged): the box stays free text
        return []
    return [(f"{b.name} - {b.strength}, {b.n_photons} photons", b.name) for b in beams
            if b.n_photons > 0]


def track_widget_metadata() -> dict[str, Any]:
    """The parameter metadata that gives the dialog the beam list (empty when the
    Processing GUI is not importable, e.g. a build without it)."""
    try:
        wrapper = _wrapper_class()
    except ImportError:
        return {}
    return {"widget_wrapper": {"class": wrapper}}


_CLASS: Any = None


def _wrapper_class() -> Any:
    global _CLASS
    if _CLASS is not None:
        return _CLASS
    from processing.gui.wrappers import WidgetWrapper
    from qgis.PyQt.QtWidgets import QComboBox

    class TrackWidgetWrapper(WidgetWrapper):  # type: ignore[misc, valid-type]
        """An editable list of the photon file's beams."""

        def createWidget(self, **kwargs: Any) -> Any:  # noqa: N802 - QGIS API
            box = QComboBox()
            box.setEditable(True)
            box.setToolTip("the file's beams (empty: every beam's first with photons as "
                           "the reader chooses); or type a MABEL channel number or 'most'")
            box.currentTextChanged.connect(lambda _: self.widgetValueHasChanged.emit(self))
            return box

        def postInitialize(self, wrappers: list[Any]) -> None:  # noqa: N802 - QGIS API
            for w in wrappers:
                if w.parameterDefinition().name() == "INPUT":
                    self._fill(w.parameterValue())
                    w.widgetValueHasChanged.connect(
                        lambda wr: self._fill(wr.parameterValue()))

        def _fill(self, path: Any) -> None:
            box = self.widget
            text = box.currentText()
            box.blockSignals(True)
            box.clear()
            box.addItem("", "")
            for label, beam in file_beams(str(path or "")):
                box.addItem(label, beam)
            box.setEditText(text)
            box.blockSignals(False)

        def setValue(self, value: Any) -> None:  # noqa: N802 - QGIS API
            self.widget.setEditText("" if value is None else str(value))

        def value(self) -> str:
            box = self.widget
            i = box.findText(box.currentText())
            if i > 0 and box.itemData(i):
                return str(box.itemData(i))
            return box.currentText().strip()

    _CLASS = TrackWidgetWrapper
    return _CLASS
