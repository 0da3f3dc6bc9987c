"""Shared pytest setup: the pure cores import straight from src/ (no build needed)."""
from __future__ import annotations

import sys
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
for package_dir in sorted((REPO_ROOT / "src").iterdir()):
    if (package_dir / "setup.py").exists() and str(package_dir) not in sys.path:
        sys.path.insert(0, str(package_dir))
