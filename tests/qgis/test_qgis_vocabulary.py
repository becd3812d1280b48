"""The QGIS parameters speak the one vocabulary (canopyblocks.options): a parameter named
like a table option (``keyword.upper()``, or the option's ``qgis`` name) has its kind and,
for a choice, its names in its order with its default."""

from __future__ import annotations

import pytest

pytestmark = [pytest.mark.qgis]


def _algorithms():  # noqa: ANN202
    from qgis.core import QgsApplication

    return [a for a in QgsApplication.processingRegistry().algorithms()
            if a.provider() is not None and a.provider().id() == "canopyblocks"]


def _kinds() -> dict[str, tuple[type, ...]]:
    from qgis.core import (
        QgsProcessingParameterBoolean,
        QgsProcessingParameterCrs,
        QgsProcessingParameterEnum,
        QgsProcessingParameterFeatureSink,
        QgsProcessingParameterFile,
        QgsProcessingParameterFileDestination,
        QgsProcessingParameterFolderDestination,
        QgsProcessingParameterMultipleLayers,
        QgsProcessingParameterNumber,
        QgsProcessingParameterString,
    )

    return {"choice": (QgsProcessingParameterEnum,),
            "number": (QgsProcessingParameterNumber, QgsProcessingParameterString),
            "file": (QgsProcessingParameterFile, QgsProcessingParameterFileDestination,
                     QgsProcessingParameterMultipleLayers),
            "folder": (QgsProcessingParameterFolderDestination,),
            "crs": (QgsProcessingParameterCrs, QgsProcessingParameterString),
            "switch": (QgsProcessingParameterBoolean, QgsProcessingParameterFeatureSink),
            "text": (QgsProcessingParameterString,)}


def test_every_qgis_parameter_of_a_table_name_has_its_meaning(qgis_session) -> None:
    from canopyblocks.options import OPTIONS

    by_name = {o.qgis_name: o for o in OPTIONS.values()}
    kinds = _kinds()
    seen = set()
    for alg in _algorithms():
        for p in alg.parameterDefinitions():
            spec = by_name.get(p.name())
            if spec is None or p.name() == "INPUT":
                continue
            seen.add(p.name())
            assert isinstance(p, kinds[spec.kind]), (alg.name(), p.name(), type(p).__name__)
            if spec.kind == "choice":
                names = [o.split(":")[0].split(" ")[0] for o in p.options()]
                # the table's names, in its order (an algorithm may offer fewer)
                assert names == [c for c in spec.choices if c in names], (alg.name(), names)
                assert set(names) <= set(spec.choices), (alg.name(), p.name(), names)
                if spec.default is not None:
                    assert names[int(p.defaultValue())] == spec.default, (alg.name(), p.name())
    assert {"PRESET", "PHOTON_RATE", "WIDTH", "CRS"} <= seen, seen


def test_simulate_speaks_photon_rate_not_preset(qgis_session) -> None:
    sim = next(a for a in _algorithms() if a.name() == "simulate")
    names = {p.name() for p in sim.parameterDefinitions()}
    assert "PHOTON_RATE" in names and "PRESET" not in names
