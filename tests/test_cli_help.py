"""Every `bin/flaair` subcommand explains itself: `--help` exits 0 with a usage line, no traceback."""
from __future__ import annotations

import pytest

from flaair_tools.cli import SUBCOMMANDS
from rosproc import FLAAIR, isolated_env, run


@pytest.mark.parametrize("command", sorted(SUBCOMMANDS))
def test_help(command: str) -> None:
    result = run([FLAAIR, command, "--help"], isolated_env(), 120)
    assert result.returncode == 0, result.stderr[-2000:]
    assert "usage:" in result.stdout.lower() and "Traceback" not in result.stderr, result.stdout[:500]


def test_bare_flaair_lists_every_subcommand() -> None:
    result = run([FLAAIR], isolated_env(), 60)
    assert all(name in result.stdout + result.stderr for name in SUBCOMMANDS)
