"""What the algorithm dialogs show: no internal words, plain numbers, an Advanced group,
one help page per algorithm (and the pages in docs/qgis match the algorithms)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

pytestmark = pytest.mark.qgis

ROOT = Path(__file__).resolve().parents[2]
INTERNAL = re.compile(r"seed[- ]0\d\d|seeds 0\d\d|DESIGN|bit for bit|issue \d", re.IGNORECASE)


def _algorithms(qgis_session):  # noqa: ANN001, ANN202
    from qgis.core import QgsApplication

    algs = [a for a in QgsApplication.processingRegistry().algorithms()
            if a.provider() is not None and a.provider().id() == "canopyblocks"]
    assert len(algs) == 13
    return algs


def test_no_internal_words_and_no_double_optional(qgis_session) -> None:
    from qgis.core import QgsProcessingParameterDefinition

    for alg in _algorithms(qgis_session):
        texts = [alg.shortHelpString(), alg.displayName()]
        for p in alg.parameterDefinitions():
            texts.append(p.description())
            texts += list(p.options()) if hasattr(p, "options") else []
            if p.flags() & QgsProcessingParameterDefinition.FlagOptional:
                # QGIS writes "[optional]" itself; a label saying it too reads twice
                assert "optional" not in p.description().lower(), (alg.name(), p.name())
        for t in texts:
            assert not INTERNAL.search(t), (alg.name(), INTERNAL.search(t).group(0), t)


def test_numbers_are_shown_plain(qgis_session) -> None:
    from qgis.core import QgsProcessingParameterNumber

    seen = 0
    for alg in _algorithms(qgis_session):
        for p in alg.parameterDefinitions():
            if not (isinstance(p, QgsProcessingParameterNumber)
                    and p.dataType() == QgsProcessingParameterNumber.Double):
                continue
            decimals = p.metadata()["widget_wrapper"]["decimals"]
            d = p.defaultValue()
            if isinstance(d, (int, float)):
                seen += 1
                # what the spin box shows is what one would write
                assert f"{float(d):.{decimals}f}" == (f"{float(d):g}" if float(d) % 1
                                                      else f"{float(d):.1f}"), (
                    alg.name(), p.name(), d, decimals)
    assert seen >= 10
    k = _by_id(qgis_session, "blockheights").parameterDefinition("K_SIGMA")
    assert f"{k.defaultValue():.{k.metadata()['widget_wrapper']['decimals']}f}" == "2.5"


def _by_id(qgis_session, alg_id: str):  # noqa: ANN001, ANN202
    return next(a for a in _algorithms(qgis_session) if a.name() == alg_id)


def test_rarely_changed_parameters_are_advanced(qgis_session) -> None:
    from qgis.core import QgsProcessingParameterDefinition

    alg = _by_id(qgis_session, "blockheights")
    adv = {p.name() for p in alg.parameterDefinitions()
           if p.flags() & QgsProcessingParameterDefinition.FlagAdvanced}
    main = {p.name() for p in alg.parameterDefinitions() if not p.isDestination()} - adv
    assert main == {"INPUT", "TRACK", "LENGTHS", "PRESET"}, main
    assert len(adv) >= 10


def test_each_algorithm_has_its_own_help_page(qgis_session) -> None:
    from qgis_plugin.help_pages import help_page

    algs = _algorithms(qgis_session)
    urls = {a.helpUrl() for a in algs}
    assert len(urls) == 13
    for alg in algs:
        page = ROOT / "docs" / "qgis" / f"{alg.name()}.md"
        assert alg.helpUrl().endswith(f"docs/qgis/{alg.name()}.md")
        assert page.exists(), f"{page} missing: run python -m qgis_plugin.help_pages docs/qgis"
        assert page.read_text(encoding="utf-8") == help_page(alg), (
            f"{page} is out of date: run python -m qgis_plugin.help_pages docs/qgis")


#: QGIS API the plugin calls that newer releases added, with the release that added it.
NEWER_API = {
    "Qgis.Aggregate": (3, 36),  # was QgsAggregateCalculator.Aggregate
    "QgsMapLayerElevationProperties.Property": (3, 36),  # scoped enum
    "Qgis.GeometryType": (3, 30),  # was QgsWkbTypes.GeometryType
    "Qgis.AltitudeClamping": (3, 26),
    "QgsProcessingOutputVariant": (3, 24),
    "respectLayerSymbology": (3, 26),
}


def test_minimum_qgis_version_is_true_to_the_api_called() -> None:
    """metadata.txt's qgisMinimumVersion is the newest release whose API the plugin calls."""
    source = "\n".join(p.read_text(encoding="utf-8")
                       for p in (ROOT / "qgis_plugin").rglob("*.py"))
    used = {name: v for name, v in NEWER_API.items() if name in source}
    assert used, "the inventory of newer API found nothing: update NEWER_API"
    need = max(used.values())
    meta = (ROOT / "metadata.txt").read_text(encoding="utf-8")
    stated = re.search(r"^qgisMinimumVersion=(\d+)\.(\d+)", meta, re.MULTILINE)
    assert stated is not None
    assert (int(stated.group(1)), int(stated.group(2))) == need, (stated.group(0), used)
