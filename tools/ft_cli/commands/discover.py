"""./ft discover DATA --out DIR: force_discovery's command line (see its cli module)."""
from __future__ import annotations


def add_arguments(p):
    from force_discovery.cli import add_arguments as add
    add(p)


def run(args) -> int:
    from force_discovery.cli import main
    return main(args)
