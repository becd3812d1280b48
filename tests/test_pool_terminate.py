"""The process pool ends when a unit fails, even if a worker swallows its SIGTERM.

A worker's ``SystemExit`` at SIGTERM can be swallowed (raised inside a ``__del__`` or a C
callback, or caught by a unit's ``except BaseException``); the pool's ``terminate`` then
waited for ever on a worker blocked on its queue.  Each case runs in a subprocess with a
time limit, so a regression fails instead of hanging the suite.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
import time

import pytest

SCRIPT = textwrap.dedent('''
    import sys, time
    from canopyblocks.workflows import backends
    from canopyblocks.errors import InputError

    MODE = sys.argv[1]
    backends._CLEANUP_GRACE_S = 2

    def unit(i):
        if i == 0:
            time.sleep(0.5)
            raise InputError("unit 0 is bad")
        end = time.monotonic() + (3.0 if MODE == "returns" else 1e9)
        while time.monotonic() < end:
            try:
                time.sleep(0.05)
            except BaseException:  # swallows the SIGTERM's SystemExit
                pass
        return i

    try:
        backends.run_items(unit, [0, 1], backend="processes", workers=2, start="fork")
    except InputError as e:
        print("refused:", e)
''')


@pytest.mark.parametrize("mode", ["returns", "never-returns"])
def test_pool_ends_when_a_worker_swallows_sigterm(mode: str) -> None:
    t0 = time.monotonic()
    proc = subprocess.run([sys.executable, "-c", SCRIPT, mode], capture_output=True,
                          text=True, timeout=60)
    took = time.monotonic() - t0
    assert proc.returncode == 0, proc.stderr
    assert "refused: unit 0 is bad" in proc.stdout, (proc.stdout, proc.stderr)
    assert took < 30, took  # the grace of 2 s, not for ever
