"""Offline correction: the live correction core and scoring applied to recorded bags and DAQ
campaigns (`./ft bag correct`, `./ft bag plot`). Composes force_correction.core with bag_tools.
The names below are imported from their modules on first use."""
from force_tester_common.core.lazy import lazy_exports

_EXPORTS = {'CorrectionSetup': 'pipeline', 'correct': 'pipeline', 'CorrectionResult': 'result',
            'PullRecord': 'result'}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
