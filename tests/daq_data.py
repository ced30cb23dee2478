"""Synthetic DAQ campaigns for the bag and offline-correction tests (pull-like records)."""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np

from force_tester_common.core.correction import MASS_KG

REPO = Path(__file__).resolve().parents[1]
SRC_DIRS = [REPO / 'src' / p for p in ('bag_tools', 'force_tester_common', 'force_correction',
                                       'force_tester_sim')]
MSG_DIR = REPO / 'src' / 'force_tester_msgs' / 'msg'
RATE = 50000.0
T0 = 1_700_000_000_000_000_000
N = 1500  # samples per synthetic pull (30 ms)


def synth(n=N, seed=0, peak=2000.0, optional=True):
    """A pull-like record: a smooth tension pulse with a break, accel ringing, noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / RATE
    tc = t[n // 2]
    pulse = peak * np.exp(-((t - tc) / 2e-3) ** 2) * (t < tc + 1e-3)
    accel = 50 * np.sin(2 * np.pi * 900 * t) * np.exp(-t / 0.01) + rng.normal(0, 0.5, n)
    ch = {'time_s': t,
          'encoder_position_m': 1.2 * t + 0.5 * t * t,
          'accel_axial_m_s2': accel,
          'force_moving_n': pulse + MASS_KG * accel + rng.normal(0, 0.3, n),
          'force_stationary_n': pulse + rng.normal(0, 0.3, n)}
    if optional:
        ch.update(motor_current_a=rng.normal(3, 0.1, n), motor_voltage_v=rng.normal(40, 1, n),
                  motor_velocity_cmd_m_s=np.full(n, 4.572), accel_lateral_m_s2=rng.normal(0, 1, n),
                  accel_vertical_m_s2=rng.normal(0, 1, n))
    return ch


def meta(s, **kw):
    return {'set': s, 'coupon_lbf': 200.0 * s, 'velocity_fps': 3.0 + s, 'decel_g': -0.5 * (s > 3),
            **kw}


def make_pulls(k=3, start=None, **kw):
    out = []
    for i in range(k):
        m = meta(1 + i % 2)
        if start is not None:
            m['start_ns'] = start + i * (N * 20_000 + 5_000_000)
            m['pull_id'] = 100 + i
        out.append((m, synth(seed=i, peak=1000.0 * (i + 1), **kw)))
    return out


def run_cli(*args, module='bag_tools.cli'):
    """`./ft bag ARGS` in a new process: bag_tools' own commands, or with
    module='force_correction.offline.cli' the full ./ft bag (correct and plot too)."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(map(str, SRC_DIRS)),
               _ROS_WHEELS_BOOTSTRAP_COMPLETE='1')
    return subprocess.run([sys.executable, '-m', module, *map(str, args)],
                          capture_output=True, text=True, env=env, timeout=120)


def removed_warning(command: str, left: Path) -> re.Pattern:
    """The warning of `./ft bag COMMAND` that it removed LEFT, a killed writer's leftover: its path whole, or as
    '.../PARENT/NAME' when the whole line would be too long (bag_tools.cli.shorten)."""
    shown = f'(?:{re.escape(str(left))}|\\.\\.\\./{re.escape(left.parent.name)}/{re.escape(left.name)})'
    return re.compile(rf"\./ft bag {command}: warning: removed '{shown}', left unfinished by a writer that is gone")


def no_partials(folder: Path):
    return [p.name for p in folder.iterdir() if p.name.startswith('.')]


def write_lvm(path: Path, volts: dict, rate: float, fmt: str = '%.9E', units: dict | None = None) -> Path:
    """A LabVIEW Measurement File as LabVIEW writes it: tab separated, one X column, Delta_X per channel;
    units: {channel: its Y_Unit_Label} (default Volts)."""
    names = list(volts)
    k = len(names)
    tab = '\t'
    head = ['LabVIEW Measurement\t', 'Writer_Version\t2', 'Reader_Version\t2', 'Separator\tTab',
            'Decimal_Separator\t.', 'Multi_Headings\tNo', 'X_Columns\tOne', 'Time_Pref\tRelative',
            'Operator\tlab', 'Date\t2026/11/24', 'Time\t12:00:00.000', '***End_of_Header***\t', '\t',
            f'Channels\t{k}' + tab * k, 'Samples' + ''.join(f'\t{len(volts[c])}' for c in names) + tab,
            'Date' + '\t2026/11/24' * k + tab, 'Time' + '\t12:00:00.000' * k + tab,
            'Y_Unit_Label' + ''.join(f'\t{(units or {}).get(c, "Volts")}' for c in names) + tab,
            'X_Dimension' + '\tTime' * k + tab,
            'X0' + '\t0.0000000000000000E+0' * k + tab, 'Delta_X' + f'\t{1 / rate:.6E}' * k + tab,
            '***End_of_Header***' + tab * (k + 1), 'X_Value\t' + tab.join(names) + '\tComment']
    n = len(volts[names[0]])
    cols = np.column_stack([np.arange(n) / rate] + [volts[c] for c in names])
    body = '\n'.join(tab.join(fmt % v for v in row) for row in cols)
    path.write_text('\n'.join(head) + '\n' + body + '\n')
    return path


#: the drop impactor's DAQ (a piezo cell and an accelerometer in volts, compression positive) and its channel map
FORCE_MV_PER_N = 0.225     # piezo load cell, mV/N
ACCEL_MV_PER_G = 1.023     # accelerometer, mV/g
IMPACTOR_CHANNEL_MAP = {
    'channels': {
        'force_moving_n': {'source': 'Load cell', 'unit': 'V', 'sensitivity': f'{FORCE_MV_PER_N} mV/N',
                           'sign': 'compression'},
        'accel_axial_m_s2': {'source': 'Accel', 'unit': 'V', 'sensitivity': f'{ACCEL_MV_PER_G} mV/g',
                             'sign': 'compression'},
    },
    'absent': ['force_stationary_n', 'encoder_position_m'],
}


def write_mf4(path, volts: dict, rate: float):
    from asammdf import MDF, Signal
    n = len(next(iter(volts.values())))
    t = np.arange(n) / rate
    mdf = MDF(version='4.10')
    mdf.append([Signal(v, t, name=name, unit='V') for name, v in volts.items()])
    mdf.save(str(path), overwrite=True)
    mdf.close()
    return path


def write_uff(path, volts: dict, rate: float):
    import pyuff
    uff = pyuff.UFF(str(path))
    for i, (name, v) in enumerate(volts.items()):
        uff.write_sets(pyuff.prepare_58(
            func_type=1, rsp_node=i + 1, rsp_dir=3, ref_node=0, ref_dir=0, id1=name, data=np.asarray(v),
            x=np.arange(len(v)) / rate,
            abscissa_spacing=1, abscissa_min=0.0, abscissa_inc=1.0 / rate, ordinate_axis_units_lab='V',
            abscissa_axis_units_lab='s', rsp_ent_name=name, ref_ent_name='none', abscissa_spec_data_type=17,
            ordinate_spec_data_type=0, orddenom_spec_data_type=0), mode='add' if i else 'overwrite')
    return path
