"""ROS-free physics core of force_tester_sim (numpy/scipy/yaml only)."""
from force_tester_common.core.units import FT_M, G_M_S2, LBF_N

from .chain import ChainParams, chain_rhs, force_move, force_stat, linear_matrices, tension
from .errors import SimError
from .integrate import ChainTrajectory, integrate_chain, integrate_reference
from .motion import MotionSource, PrescribedMotion, hold_time_s, nominal_slack_m
from .params import (
                     NOMINAL_YAML,
                     DaqParams,
                     DriveParams,
                     ForceChainParams,
                     RigParams,
                     SensorParams,
                     TestSet,
                     load_rig,
                     rig_from_dict,
)
from .pull import (
                     CHANNELS,
                     PullResult,
                     PullSpec,
                     chain_params,
                     make_pull_specs,
                     motion_for,
                     nominal_pull_spec,
                     run_pull,
                     sample_stamps_ns,
                     sample_times_s,
)
from .simulate import simulate_pull

__all__ = [
    'SimError', 'FT_M', 'G_M_S2', 'LBF_N',
    'DaqParams', 'DriveParams', 'ForceChainParams', 'RigParams', 'SensorParams', 'TestSet', 'load_rig',
    'rig_from_dict', 'NOMINAL_YAML',
    'ChainParams', 'chain_rhs', 'force_move', 'force_stat', 'linear_matrices', 'tension',
    'MotionSource', 'PrescribedMotion', 'hold_time_s', 'nominal_slack_m',
    'ChainTrajectory', 'integrate_chain', 'integrate_reference',
    'CHANNELS', 'PullResult', 'PullSpec', 'chain_params', 'make_pull_specs', 'motion_for',
    'nominal_pull_spec', 'run_pull', 'sample_stamps_ns', 'sample_times_s', 'simulate_pull',
]
