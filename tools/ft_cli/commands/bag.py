"""./ft bag COMMAND: bag_tools' commands plus force_correction's correct and plot."""
from __future__ import annotations

import argparse

PASSTHROUGH = 'bag_args'  # every argument goes to the bag tool's own parser
ADD_HELP = False  # --help too


def add_arguments(p):
    p.add_argument('bag_args', nargs=argparse.REMAINDER)


def run(args) -> int:
    from force_correction.offline.cli import main
    return main(args.bag_args)
