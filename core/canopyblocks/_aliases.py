"""Old module paths of canopyblocks, kept working after the modules moved into rooms.

``import canopyblocks.track_blocks`` gives the module now at ``canopyblocks.workflows.blocks``
(the same module object, so patches and ``isinstance`` behave as before). One table, one
import hook; :mod:`canopyblocks` installs it. New code imports the new paths.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import sys
from types import ModuleType
from typing import Any

#: old module -> new module (a package entry covers its submodules too)
MOVED_MODULES: dict[str, str] = {
    "canopyblocks.waveforms.arguments": "canopyblocks.waveforms.waveform_checks",
    "canopyblocks.outputs.gedi_l1b_layout": "canopyblocks.outputs.h5_gedi_l1b",
    "canopyblocks.track_blocks": "canopyblocks.workflows.blocks",
    "canopyblocks.track_workers": "canopyblocks.workflows.blocks_tracks",
    "canopyblocks.track_segments": "canopyblocks.workflows.segments",
    "canopyblocks.waveform_footprints": "canopyblocks.workflows.waveforms",
    "canopyblocks.waveform_workers": "canopyblocks.workflows.waveforms_beams",
    "canopyblocks.whole_chain": "canopyblocks.workflows.chain.run",
    "canopyblocks.waveform_chain": "canopyblocks.workflows.chain.waveforms",
    "canopyblocks.chain_result": "canopyblocks.workflows.chain.result",
    "canopyblocks.chain_tiles": "canopyblocks.workflows.chain.tiles",
    "canopyblocks.granule_blocks": "canopyblocks.workflows.blocks_granules",
    "canopyblocks.utc_time": "canopyblocks.readers.utc_time",
    "canopyblocks.chain_report": "canopyblocks.workflows.chain.report",
    "canopyblocks.workflows.chain_facts": "canopyblocks.workflows.chain.facts",
    "canopyblocks.workflows.chain_figures": "canopyblocks.workflows.chain.figures",
    "canopyblocks.workflows.chain_flash_dual": "canopyblocks.workflows.chain.flash_dual",
    "canopyblocks.workflows.chain_glossary": "canopyblocks.workflows.chain.glossary",
    "canopyblocks.workflows.chain_photon_report": "canopyblocks.workflows.chain.photon_report",
    "canopyblocks.workflows.chain_report": "canopyblocks.workflows.chain.report",
    "canopyblocks.workflows.chain_result": "canopyblocks.workflows.chain.result",
    "canopyblocks.workflows.chain_tiles": "canopyblocks.workflows.chain.tiles",
    "canopyblocks.workflows.chain_waveform_report": "canopyblocks.workflows.chain.waveform_report",
    "canopyblocks.workflows.chain_waveforms": "canopyblocks.workflows.chain.waveforms",
    "canopyblocks.batch.backends": "canopyblocks.workflows.backends",
    "canopyblocks.batch": "canopyblocks.workflows.batch",
    "canopyblocks.validation.validation_files": "canopyblocks.workflows.validate",
    "canopyblocks.validation.coregistration_files": "canopyblocks.workflows.coregister",
    "canopyblocks.validation.bias_calibration_files": "canopyblocks.workflows.calibrate",
    "canopyblocks.photon_order": "canopyblocks.readers.photon_order",
    "canopyblocks.simulate.classify": "canopyblocks.blocks.step_classify",
    "canopyblocks.simulate.footprints": "canopyblocks.reference.footprint_index",
    "canopyblocks.outputs.atomic": "canopyblocks.atomic",
}


#: module -> {name that moved out of it: module that holds it now}
MOVED_NAMES: dict[str, dict[str, str]] = {
    "canopyblocks.reference.footprint": {
        "block_footprint_reference": "canopyblocks.reference.footprint_blocks",
        "BlockStatistic": "canopyblocks.reference.footprint_blocks",
    },
    "canopyblocks.validation": {
        "FileValidation": "canopyblocks.workflows.validate",
        "calibrate_bias_file": "canopyblocks.workflows.calibrate",
        "coregister_file": "canopyblocks.workflows.coregister",
        "validate_file": "canopyblocks.workflows.validate",
        "validate_footprints_file": "canopyblocks.workflows.validate",
        "write_offsets": "canopyblocks.workflows.coregister",
    },
    "canopyblocks.validation.calibration": {
        "calibrate_reference_rasters": "canopyblocks.workflows.calibrate",
    },
    "canopyblocks.validation.footprints": {
        "validate_footprints_file": "canopyblocks.workflows.validate",
    },
}


def moved_name(module: str, name: str) -> Any:
    """The object ``name`` that moved out of ``module`` (for that module's ``__getattr__``)."""
    target = MOVED_NAMES.get(module, {}).get(name)
    if target is None:
        raise AttributeError(f"module {module!r} has no attribute {name!r}")
    return getattr(importlib.import_module(target), name)


def new_name(fullname: str) -> str | None:
    """The new path of an old module path, or None when ``fullname`` did not move."""
    for old, new in MOVED_MODULES.items():
        if fullname == old:
            return new
        if fullname.startswith(old + "."):
            return new + fullname[len(old):]
    return None


class _AliasLoader(importlib.abc.Loader):
    def __init__(self, target: str) -> None:
        self.target = target

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType | None:
        return None

    def exec_module(self, module: ModuleType) -> None:
        # the import system returns what sys.modules holds under the old name afterwards
        sys.modules[module.__name__] = importlib.import_module(self.target)


class _AliasFinder(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname: str, path: Any = None,
                  target: Any = None) -> importlib.machinery.ModuleSpec | None:
        new = new_name(fullname)
        if new is None:
            return None
        return importlib.machinery.ModuleSpec(fullname, _AliasLoader(new))


def install() -> None:
    """Put the alias hook first on ``sys.meta_path`` (once): an old path is answered by
    its new module even where a stale copy of the old file lies on ``sys.path``."""
    if not any(isinstance(f, _AliasFinder) for f in sys.meta_path):
        sys.meta_path.insert(0, _AliasFinder())
