"""What a user sees on a terminal: a progress bar (also on a pseudo-terminal that reports
no size, as `script`, CI consoles and some IDEs give), each warning once, no
matplotlib noise."""

from __future__ import annotations

import os
import pty
import select
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _on_a_pty(args: list[str], cwd: Path) -> tuple[int, str]:
    """Run ``args`` with stdin/stdout/stderr on a fresh pseudo-terminal (size 0 x 0)."""
    master, slave = pty.openpty()
    env = {k: v for k, v in os.environ.items() if k not in ("COLUMNS", "LINES")}
    proc = subprocess.Popen(args, stdin=slave, stdout=slave, stderr=slave, cwd=cwd, env=env,
                            close_fds=True)
    os.close(slave)
    chunks = []
    while True:
        ready, _, _ = select.select([master], [], [], 0.2)
        if ready:
            try:
                data = os.read(master, 65536)
            except OSError:
                break
            if not data:
                break
            chunks.append(data)
        elif proc.poll() is not None:
            break
    proc.wait(timeout=300)
    os.close(master)
    return proc.returncode, b"".join(chunks).decode("utf-8", "replace")


def test_progress_bar_on_a_sizeless_pseudo_terminal(sample, tmp_path) -> None:
    code, out = _on_a_pty(
        [sys.executable, "-m", "canopyblocks", "blocks",
         str(sample("icesat2/vegr_atl03_clip.h5")), "--beam", "gt1r", "--length", "25",
         "-o", str(tmp_path / "b.gpkg")], tmp_path)
    assert code == 0, out
    assert "blocks:" in out and "%|" in out, out[-2000:]
    assert "Axes3D" not in out


def test_a_warning_is_said_once(capsys) -> None:
    """The CLI's log handler drops a warning it has already shown in this run."""
    import logging

    from canopyblocks.cli.log_setup import setup_logging

    setup_logging(0, False)
    log = logging.getLogger("canopyblocks.test_terminal")
    for _ in range(3):
        log.warning("the same warning from every fold")
    log.warning("another warning")
    err = capsys.readouterr().err
    assert err.count("the same warning from every fold") == 1
    assert err.count("another warning") == 1


def _commands() -> list[str]:
    from canopyblocks.cli import cli

    return sorted(cli.commands)


@pytest.mark.parametrize("command", _commands())
def test_help_has_no_internal_words(command: str) -> None:
    from click.testing import CliRunner

    from canopyblocks.cli import cli

    r = CliRunner().invoke(cli, [command, "--help"])
    assert r.exit_code == 0
    for word in ("DESIGN 1", "DESIGN 2", "seed 00", "seed-00", "issue "):
        assert word not in r.output, (command, word)
