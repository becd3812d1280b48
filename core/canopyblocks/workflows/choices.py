"""The choices of the front doors, made once: which estimators the options name.

The command line and the QGIS algorithms pass what the user gave; the choice of what it
means (a preset, parts replacing those of the paper's method) is made here.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ..blocks.estimators import Estimators

__all__ = ["estimators_from_options", "refuse_unused_k_sigma"]


def estimators_from_options(preset: str | None, noise: str | None, ground: str | None,
                            top: str | None, min_signal_conf: int | None = None
                            ) -> Estimators:
    """The Estimators the options name.

    ``preset`` None (not given): the recommended preset (``atl08``) when no part is
    named, else the named parts (``noise``, ``ground``, ``top``) replacing those of the
    paper's method; a given ``preset`` has its parts replaced by the named ones.
    """
    from dataclasses import replace

    from ..blocks.estimators import RECOMMENDED_PRESET
    from ..blocks.estimators import preset as named_preset

    parts = {"noise": noise, "ground": ground, "top": top}
    base = preset or ("paper" if any(v is not None for v in parts.values())
                      else RECOMMENDED_PRESET)
    est = named_preset(base)
    changes: dict[str, Any] = {k: v for k, v in parts.items()
                               if v is not None and v != getattr(est, k)}
    if min_signal_conf is not None and (noise == "conf" or est.noise == "conf"):
        changes["min_signal_conf"] = min_signal_conf
    if changes:
        est = replace(est, **changes, name="custom" if preset is None else f"{preset}+")
    return est


def refuse_unused_k_sigma(estimators: Estimators, k_sigma: float) -> None:
    """Refuse a noise threshold the user gave (even at its default) that ``estimators``
    do not use, naming the option or preset to change.

    Raises
    ------
    InputError
        When the estimators' noise filter is not the paper's sigma filter.
    """
    from ..blocks.estimators import unused_k_sigma
    from ..errors import InputError

    if (why := unused_k_sigma(estimators, k_sigma)) is not None:
        raise InputError(why)
