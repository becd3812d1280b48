"""Corpus cases expected to fail (none today).

An entry ``case id -> reason`` marks a case ``xfail(strict=False)`` so it is rechecked on
every run; add one only for a defect being fixed, with the reason, and remove it once the
case passes (issue 10).
"""

from __future__ import annotations

XFAIL: dict[str, str] = {}
