"""Every `bin/flaair` subcommand explains itself: `--help` exits 0 with a usage line, no traceback.

All subcommands are asked in one process (`flaair_tools.cli.main`, what bin/flaair runs), each
with its own captured output; one process instead of one per command keeps this under 10 s.
"""

from __future__ import annotations

import json
import sys

import pytest

from flaair_tools.cli import SUBCOMMANDS
from rosproc import FLAAIR, isolated_env, run

SCRIPT = """
import contextlib, io, json, sys, traceback
from flaair_tools.cli import SUBCOMMANDS, main
results = {}
for name in sorted(SUBCOMMANDS):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main([name, "--help"])
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
        except BaseException:
            code, err = 99, io.StringIO(traceback.format_exc())
    results[name] = {"code": code, "stdout": out.getvalue(), "stderr": err.getvalue()}
print(json.dumps(results))
"""


@pytest.mark.slow  # a new interpreter per subcommand
@pytest.mark.timeout(180)
def test_every_subcommand_has_a_help() -> None:
    result = run([sys.executable, "-c", SCRIPT], isolated_env(), 170)
    assert result.returncode == 0, result.stderr[-3000:]
    results = json.loads(result.stdout.strip().splitlines()[-1])
    assert sorted(results) == sorted(SUBCOMMANDS)
    bad = {
        name: r
        for name, r in results.items()
        if r["code"] != 0 or "usage:" not in r["stdout"].lower() or "Traceback" in r["stderr"]
    }
    assert bad == {}, {
        name: (r["code"], r["stdout"][:300], r["stderr"][-600:]) for name, r in bad.items()
    }


def test_bare_flaair_lists_every_subcommand() -> None:
    result = run([FLAAIR], isolated_env(), 60)
    assert all(name in result.stdout + result.stderr for name in SUBCOMMANDS)
