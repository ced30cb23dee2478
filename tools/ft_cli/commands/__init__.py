"""The subcommands of ./ft, in the order --help lists them: name, where it lives, one line of help.

A command is a module (or a class in one) with add_arguments(parser) and run(args) -> exit code;
PASSTHROUGH names the argument that takes whatever the subcommand's parser does not know (pytest's,
a node's or the bag tool's options), ADD_HELP = False passes --help on too. Only the command that
runs is imported, so `./ft --help` and each command start without the others' imports.
"""
from __future__ import annotations

import importlib

COMMANDS = (
    ('demo', 'demo', 'run sim + correction + validator over DDS on the test sets, record a bag, print per-set scores'),
    ('monitor', 'monitor', 'live terminal scoreboard of a running graph or a bag played back (per pull, per set, '
                           'health, nodes)'),
    ('view', 'view', 'serve the local web viewer (Foxglove Studio 1.48.0) with the workspace layout, connected to '
                     'the monitor, or on a recorded bag (--bag); prints the URL'),
    ('thesis', 'thesis', "the thesis's top-speed predictions and Tables 7-9 beside ours (--json FILE for the figures)"),
    ('discover', 'discover', 'find what the simulation gets wrong in measured data: name the cause, extend the '
                             'model, measure the gain'),
    ('test', 'workspace:Test', 'run the test suite (pytest); extra arguments go to pytest'),
    ('run', 'workspace:Run', 'run a node like `ros2 run PACKAGE EXECUTABLE [--ros-args ...]`'),
    ('bag', 'bag', 'record, play, inspect, convert and correct rosbag2 MCAP bags (./ft bag --help)'),
    ('env', 'workspace:Env', 'print the environment as shell exports: eval "$(./ft env)"'),
    ('bench', 'workspace:Bench', 'run a benchmark script from benchmarks/ (e.g. ./ft bench correction)'),
    ('lock', 'lock', 'update requirements.lock from requirements.txt (--check: say whether it is up to date)'),
    ('wheels', 'workspace:Wheels', "download every package of the lock into DIR, for a machine with no network "
                                   "(FT_WHEELS=DIR ./ft demo there)"),
)
NAMES = frozenset(name for name, _, _ in COMMANDS)


def load(name: str):
    """The command called NAME: its module, or the class in it."""
    where = next(w for n, w, _ in COMMANDS if n == name)
    module, _, attr = where.partition(':')
    found = importlib.import_module(f'{__name__}.{module}')
    return getattr(found, attr) if attr else found
