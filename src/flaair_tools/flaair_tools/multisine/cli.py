"""`flaair multisine design|analyze`: odd random-phase multisines (docs/MULTISINE.md).

  design   write the excitation (one CSV per realization) and its multisine.yaml
  analyze  BLA, noise, odd and even distortion per channel from the runs; --model: what the
           model does not predict

`bin/flaair multisine design --help` and `bin/flaair multisine analyze --help` say more.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from flaair_common.cli_help import HelpFormatter

__all__ = ["ACTIONS", "main", "parser"]

ACTIONS = {
    "design": "flaair_tools.multisine.design_cli",
    "analyze": "flaair_tools.multisine.analyze_cli",
}
HELP = {"design": "write the excitation and its design file", "analyze": "BLA and distortion"}


def parser() -> argparse.ArgumentParser:
    """The command and each action's options (the actions' own parsers as parents)."""
    p = argparse.ArgumentParser(
        prog="flaair multisine", description=__doc__, formatter_class=HelpFormatter
    )
    actions = p.add_subparsers(dest="action", required=True, metavar="{design,analyze}")
    for name, module_name in ACTIONS.items():
        module = importlib.import_module(module_name)
        actions.add_parser(
            name,
            parents=[module.parser()],
            add_help=False,
            help=HELP[name],
            description=module.__doc__,
            formatter_class=HelpFormatter,
        )
    return p


def main(argv: list[str] | None = None) -> int:
    """Check the whole command line, then run the action's own main."""
    argv = sys.argv[1:] if argv is None else argv
    parser().parse_args(argv)  # a bad action or option: usage and exit 2 here
    return int(importlib.import_module(ACTIONS[argv[0]]).main(argv[1:]) or 0)


if __name__ == "__main__":
    sys.exit(main())
