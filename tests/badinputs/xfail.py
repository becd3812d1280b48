"""Corpus cases that fail today because of defects in files other helpers are fixing.

Marked ``xfail(strict=False)`` so they are rechecked on every run; remove an entry once its
case passes (issue 10).
"""

from __future__ import annotations

_WHY = {
    "D-las": "known limit: a LAZ header that counts fewer points than the file holds, or a bit "
             "flip in its x scale/offset, gives points consistent with the header; laspy stops "
             "at the header's count and the chunk table holds no per-chunk counts to check",
}

XFAIL: dict[str, str] = {cid: _WHY[key] for cid, key in (
    ("laz-header-count-half", "D-las"),
    ("laz-bitflip-header-2", "D-las"),
)}
