"""ROS-free core of force_correction (numpy/scipy/stdlib only)."""

from .errors import CorrectionError
from .pairing import EVENT_KINDS, AlignedPair, AlignerEvent, BlockAligner
from .params import MAX_WINDOW, CorrectionParams
from .scoring import PullAccumulator, PullScoreResult, SetStatistics, SetSummary, score_pull
from .streaming import CorrectedBlock, CorrectionState, InertialCorrector, correct_block, correct_signal, initial_state

__all__ = [
    'CorrectionError', 'MAX_WINDOW', 'CorrectionParams',
    'CorrectedBlock', 'CorrectionState', 'InertialCorrector', 'correct_block',
    'correct_signal', 'initial_state',
    'EVENT_KINDS', 'AlignedPair', 'AlignerEvent', 'BlockAligner',
    'PullAccumulator', 'PullScoreResult', 'SetStatistics', 'SetSummary', 'score_pull',
]
