"""correction_graph: correction and validator nodes composed in one process, one executor.

    correction_graph [--namespace NS ...] [--ros-args ...]

One pair in the process's namespace by default; with ``--namespace /rig1 --namespace /rig2`` one
pair per rig, each under its own namespace (topics /rig1/force, /rig1/force_corrected, ...).
"""
import argparse
import functools
import sys

from force_tester_common.ros import spin_nodes

from .correction_node import CorrectionNode
from .validator_node import ValidatorNode


def main(args=None):
    argv = list(sys.argv if args is None else args)
    ros_args = argv[argv.index('--ros-args'):] if '--ros-args' in argv else []
    own = argv[1:len(argv) - len(ros_args)]
    ap = argparse.ArgumentParser(prog='correction_graph', description=__doc__.splitlines()[0])
    ap.add_argument('--namespace', action='append', default=[], metavar='NS',
                    help='a rig namespace, e.g. /rig1 (repeat for several rigs; default: one pair, no namespace)')
    opts = ap.parse_args(own)
    factories = []
    for ns in opts.namespace or [None]:
        kw = {'namespace': ns} if ns else {}
        factories += [functools.partial(CorrectionNode, **kw), functools.partial(ValidatorNode, **kw)]
    raise SystemExit(spin_nodes(*factories, args=[argv[0], *ros_args]))
