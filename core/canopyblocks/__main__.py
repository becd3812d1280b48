"""``python -m canopyblocks`` runs the command line."""

import sys


def _entry() -> int:
    """Import the command line and run it; Ctrl-C while starting ends with one line."""
    try:
        from .cli import main

        return main()
    except KeyboardInterrupt:  # before run_main handles signals itself
        sys.stderr.write("canopyblocks: error: interrupted (Ctrl-C) while starting; "
                         "no output was written\n")
        return 130


if __name__ == "__main__":
    sys.exit(_entry())
