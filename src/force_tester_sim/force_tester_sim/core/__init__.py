"""ROS-free physics core of force_tester_sim (numpy/scipy/yaml only)."""
# The names below are loaded from their module on first use (PEP 562): importing one light module of the core
# (params, sim_config, ...) then costs no scipy. The sim node's own process only plans and publishes pulls, its
# worker process simulates them: 1.2 s less CPU for every sim node started.
import importlib

_HOMES = {
    'FT_M': 'force_tester_common.core.units', 'G_M_S2': 'force_tester_common.core.units',
    'LBF_N': 'force_tester_common.core.units', 'SimError': '.errors',
    **dict.fromkeys(('ChainParams', 'chain_rhs', 'force_move', 'force_stat', 'linear_matrices', 'tension'), '.chain'),
    **dict.fromkeys(('ChainTrajectory', 'integrate_chain', 'integrate_reference'), '.integrate'),
    **dict.fromkeys(('MotionSource', 'PrescribedMotion', 'hold_time_s', 'nominal_slack_m'), '.motion'),
    **dict.fromkeys(('NOMINAL_YAML', 'DaqParams', 'DriveParams', 'ForceChainParams', 'RigParams', 'SensorParams',
                     'TestSet', 'load_rig', 'rig_from_dict'), '.params'),
    **dict.fromkeys(('CHANNELS', 'PullResult', 'PullSpec', 'chain_params', 'make_pull_specs', 'motion_for',
                     'nominal_pull_spec', 'run_pull', 'sample_stamps_ns', 'sample_times_s'), '.pull'),
    'simulate_pull': '.simulate',
}
__all__ = list(_HOMES)


def __getattr__(name: str):
    home = _HOMES.get(name)
    if home is None:
        raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
    return getattr(importlib.import_module(home, __name__), name)
