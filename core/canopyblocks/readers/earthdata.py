"""Temporary S3 keys of NASA Earthdata for the buckets of NASA's archives (through
``earthaccess``, where installed and a login works without a prompt)."""

from __future__ import annotations

import time

__all__ = ["DAAC_BUCKETS", "earthdata_credentials"]

#: Buckets of NASA's archives (by prefix) and their data centre: ICESat-2 at NSIDC, GEDI
#: L1B/L2 at LP DAAC, GEDI L4 at ORNL DAAC.
DAAC_BUCKETS = {"nsidc-cumulus-prod-": "NSIDC", "lp-prod-": "LPDAAC",
                "ornl-cumulus-prod-": "ORNLDAAC"}
_EARTHDATA: dict[str, tuple[float, dict[str, str]]] = {}  # daac -> (time, keys)
_EARTHDATA_SECONDS = 50 * 60  # the keys last an hour


def earthdata_credentials(url: str) -> dict[str, str]:
    """Temporary S3 keys of NASA Earthdata for a NASA bucket, through ``earthaccess`` when it
    is installed and a login works without a prompt (``EARTHDATA_USERNAME``/``_PASSWORD`` or
    ``~/.netrc``); ``{}`` otherwise (the standard chain then decides)."""
    import importlib

    bucket = url.split("://", 1)[-1].split("/", 1)[0]
    daac = next((d for prefix, d in DAAC_BUCKETS.items() if bucket.startswith(prefix)), None)
    if daac is None:
        return {}
    now = time.monotonic()
    got = _EARTHDATA.get(daac)
    if got is not None and now - got[0] < _EARTHDATA_SECONDS:
        return got[1]
    try:
        ea = importlib.import_module("earthaccess")
    except ImportError:
        return {}
    try:
        if not getattr(getattr(ea, "__auth__", None), "authenticated", False):
            for strategy in ("environment", "netrc"):  # never the interactive prompt
                try:
                    ea.login(strategy=strategy)
                except Exception:  # noqa: BLE001 -- the next strategy, or none
                    continue
                if getattr(getattr(ea, "__auth__", None), "authenticated", False):
                    break
            else:
                return {}
        creds = ea.get_s3_credentials(daac=daac)
        keys = {"key": str(creds["accessKeyId"]), "secret": str(creds["secretAccessKey"]),
                "token": str(creds["sessionToken"])}
    except Exception:  # noqa: BLE001 -- no keys: the standard chain decides, and says so
        return {}
    _EARTHDATA[daac] = (now, keys)
    return keys
