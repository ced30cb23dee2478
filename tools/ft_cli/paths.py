"""Where the workspace is, and where `ros2 run` would find a node."""
from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
INSTALL = ROOT / 'install'
RUNS = ROOT / 'runs'


def executable(package: str, name: str) -> Path:
    """Where `ros2 run PACKAGE NAME` finds a node: install/<pkg>/lib/<pkg>/<name>."""
    path = INSTALL / package / 'lib' / package / name
    if not path.is_file():
        lib = INSTALL / package / 'lib' / package
        have = sorted(p.name for p in lib.iterdir()) if lib.is_dir() else []
        raise SystemExit(f"ft: error: no executable {name!r} in package {package!r}; "
                         f"expected one of {', '.join(have) or '(package not built)'}")
    return path
