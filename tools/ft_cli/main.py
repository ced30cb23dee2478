"""./ft's parser: one subcommand per entry of commands.COMMANDS; only the one that runs is imported."""
from __future__ import annotations

import argparse
import sys

from .commands import COMMANDS, NAMES, load


def build_parser(chosen: str | None = None) -> argparse.ArgumentParser:
    """Every subcommand with its help line; CHOSEN (or all of them, for None) with its arguments."""
    p = argparse.ArgumentParser(
        prog='./ft', description='The force tester workspace: live ROS 2 correction graph, bags, tests.')
    sub = p.add_subparsers(dest='command', required=True, metavar='COMMAND')
    for name, _, help_ in COMMANDS:
        if chosen is not None and name != chosen:
            sub.add_parser(name, help=help_)
            continue
        command = load(name)
        s = sub.add_parser(name, help=help_, description=help_, add_help=getattr(command, 'ADD_HELP', True))
        command.add_arguments(s)
        s.set_defaults(func=command.run, passthrough=getattr(command, 'PASSTHROUGH', None))
    return p


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    chosen = next((a for a in argv[:1] if a in NAMES), '')
    parser = build_parser(chosen)
    args, extra = parser.parse_known_args(argv)
    if extra and args.passthrough is None:
        parser.error(f"unrecognized arguments: {' '.join(extra)}")
    if extra:  # options meant for pytest, the node or the bag tool
        setattr(args, args.passthrough, extra + getattr(args, args.passthrough))
    try:
        return args.func(args)
    except KeyboardInterrupt:
        return 130


if __name__ == '__main__':
    sys.exit(main())
