"""Offline correction: the live correction core and scoring applied to recorded bags and DAQ
campaigns (`./ft bag correct`, `./ft bag plot`). Composes force_correction.core with bag_tools."""

from .pipeline import CorrectionSetup, correct
from .result import CorrectionResult, PullRecord

__all__ = ['CorrectionSetup', 'correct', 'CorrectionResult', 'PullRecord']
