"""`flaair multisine design|analyze`: odd random-phase multisines (docs/MULTISINE.md).

  design   write the excitation (one CSV per realization) and its multisine.yaml
  analyze  BLA, noise, odd and even distortion per channel from the runs; --model: what the
           model does not predict

`bin/flaair multisine design --help` and `bin/flaair multisine analyze --help` say more.
"""

from __future__ import annotations

import importlib
import sys

__all__ = ["ACTIONS", "main"]

ACTIONS = {
    "design": "flaair_tools.multisine.design_cli",
    "analyze": "flaair_tools.multisine.analyze_cli",
}
USAGE = "usage: flaair multisine {design,analyze} [options]"


def main(argv: list[str] | None = None) -> int:
    """Dispatch to the action's own main."""
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ("-h", "--help"):
        print(f"{USAGE}\n\n{__doc__}")
        return 0 if argv else 2
    if argv[0] not in ACTIONS:
        print(f"flaair multisine: unknown action {argv[0]!r}\n{USAGE}", file=sys.stderr)
        return 2
    module = importlib.import_module(ACTIONS[argv[0]])
    return int(module.main(argv[1:]) or 0)


if __name__ == "__main__":
    sys.exit(main())
