"""correction_graph: the correction and validator nodes composed in one process, one executor."""
from force_tester_common.ros import spin_nodes

from .correction_node import CorrectionNode
from .validator_node import ValidatorNode


def main(args=None):
    raise SystemExit(spin_nodes(CorrectionNode, ValidatorNode, args=args))
