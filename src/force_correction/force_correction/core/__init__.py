"""ROS-free core of force_correction (numpy/scipy/stdlib only). The names below are imported from
their modules on first use."""
from force_tester_common.core.lazy import lazy_exports

_EXPORTS = {
    'CorrectionError': 'errors', 'MAX_WINDOW': 'params', 'CorrectionParams': 'params',
    'CorrectedBlock': 'streaming', 'CorrectionState': 'streaming', 'InertialCorrector': 'streaming',
    'correct_block': 'streaming', 'correct_signal': 'streaming', 'initial_state': 'streaming',
    'EVENT_KINDS': 'pairing', 'AlignedPair': 'pairing', 'AlignerEvent': 'pairing', 'BlockAligner': 'pairing',
    'PullAccumulator': 'scoring', 'PullScoreResult': 'scoring', 'SetStatistics': 'scoring',
    'SetSummary': 'scoring', 'score_pull': 'scoring',
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
