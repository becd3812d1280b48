"""``python -m canopyblocks`` runs the command line."""

import signal
import sys


def _entry() -> int:
    """Import the command line and run it; Ctrl-C while starting ends with one line."""
    try:
        from .cli import main
    except KeyboardInterrupt:  # before run_main handles signals itself
        sys.stderr.write("canopyblocks: error: interrupted (Ctrl-C) while starting; "
                         "no output was written\n")
        return 130
    try:
        code = main()
    except KeyboardInterrupt:  # between run_main's end and here: it has reported already
        return 130
    # the command has ended and said so: a late signal changes nothing any more
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, signal.SIG_IGN)
    return code


if __name__ == "__main__":
    sys.exit(_entry())
