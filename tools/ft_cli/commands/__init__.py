"""The subcommands of ./ft, in the order --help lists them. Each has NAME, HELP,
add_arguments(parser) and run(args) -> exit code; PASSTHROUGH names the argument that takes
whatever the subcommand's parser does not know (pytest's, a node's or the bag tool's options)."""
from . import bag, demo, discover, lock, monitor, thesis
from .workspace import Bench, Env, Run, Test

COMMANDS = (demo, monitor, thesis, discover, Test, Run, bag, Env, Bench, lock)
