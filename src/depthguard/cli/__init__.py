"""The ``depthguard`` command. Each module in ``_COMMAND_MODULES`` adds its commands."""

from __future__ import annotations

import importlib
import sys

from depthguard.cli.app import app

_COMMAND_MODULES = [
    "depthguard.cli.reproduce",
    "depthguard.cli.distance",
    "depthguard.cli.depthgrid",
    "depthguard.cli.scenes",
    "depthguard.cli.bench",
    "depthguard.cli.distributed",
    "depthguard.cli.keys",
    "depthguard.cli.demo",
    "depthguard.cli.run",
    "depthguard.cli.ssm",
    "depthguard.cli.path_watch",
    "depthguard.cli.freespace",
    "depthguard.cli.monitor",
    "depthguard.cli.check_path",
    "depthguard.cli.view",
    "depthguard.cli.bag",
    "depthguard.cli.realsense",
    "depthguard.cli.calibrate",
    "depthguard.cli.learn_scene",
    "depthguard.cli.warm_up",
]

for _m in _COMMAND_MODULES:
    importlib.import_module(_m)


def main() -> None:
    """Entry point: user errors (ValueError, FileNotFoundError) print one clear line, exit 2."""
    try:
        app()
    except (ValueError, FileNotFoundError) as exc:
        print(f"depthguard: error: {exc}", file=sys.stderr)
        sys.exit(2)
