"""./ft's parser: one subcommand per entry of commands.COMMANDS."""
from __future__ import annotations

import argparse
import sys

from .commands import COMMANDS


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog='./ft', description='The force tester workspace: live ROS 2 correction graph, bags, tests.')
    sub = p.add_subparsers(dest='command', required=True, metavar='COMMAND')
    for command in COMMANDS:
        passthrough = getattr(command, 'PASSTHROUGH', None)
        s = sub.add_parser(command.NAME, help=command.HELP, add_help=getattr(command, 'ADD_HELP', True))
        command.add_arguments(s)
        s.set_defaults(func=command.run, passthrough=passthrough)
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
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
