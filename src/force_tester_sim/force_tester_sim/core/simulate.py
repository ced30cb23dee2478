"""One pull's DAQ record, from either carriage model: the prescribed motion (pull.run_pull) or
the drive coupled to the force chain (coupled.run_coupled_pull)."""
from __future__ import annotations

from typing import Dict

import numpy as np

from .params import RigParams
from .pull import PullSpec, run_pull


def simulate_pull(rig: RigParams, spec: PullSpec, noise: bool = True, drive: bool = False) -> Dict[str, np.ndarray]:
    """The DAQ export columns of one pull (keys: CHANNELS). ``drive=True``: the drive model coupled to the force
    chain instead of the prescribed carriage motion."""
    if drive:
        from .coupled import run_coupled_pull  # scipy: loaded by the process that simulates
        return run_coupled_pull(rig, spec, noise).channels
    return run_pull(rig, spec, noise).channels
