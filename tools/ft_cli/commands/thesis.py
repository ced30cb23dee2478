"""./ft thesis: the thesis's predictions (section 4.2.6) and Tables 7-9, side by side with ours.

Top speed at a 30 fps command (peak, plateau, current limit, power, distance, and the plateau's
cause decided by rerunning without damping and with a higher voltage limit), the carriage-mass
sweep, and the Table 7/8/9-shaped statistics of the reference "measured" campaign (the truth rig,
5 sets x 20 pulls, generated on first use and cached under runs/cache/ in the DAQ export format).
"""
from __future__ import annotations

import hashlib
import json
import shutil
import sys
import time
from pathlib import Path

from force_tester_common.core.units import FT_M

from ..paths import RUNS

CACHE = RUNS / 'cache'
REFERENCE_PULLS = 20     # the reference campaign: pulls per set ...
REFERENCE_SEED = 2013    # ... and its seed


def add_arguments(p):
    p.add_argument('--json', metavar='FILE', help='also write the figures as JSON')
    p.add_argument('--plots', metavar='DIR', default=str(RUNS / 'thesis'),
                   help='folder for the PNG plots (default runs/thesis)')
    p.add_argument('--pulls', type=int, default=REFERENCE_PULLS,
                   help=f'pulls per set in the reference campaign (default {REFERENCE_PULLS})')
    p.add_argument('--seed', type=int, default=REFERENCE_SEED,
                   help=f'seed of the reference campaign (default {REFERENCE_SEED})')
    p.add_argument('--no-campaign', action='store_true', help='skip the reference campaign (Tables 7-9)')
    p.add_argument('--cache', metavar='DIR', default=str(CACHE),
                   help='where the reference campaign is cached (default runs/cache)')
    from force_tester_common.engine import add_scheduler_argument
    add_scheduler_argument(p)


def cache_key(pulls: int, seed: int) -> str:
    import force_tester_sim.core as core
    from force_tester_sim.core.params import TRUTH_YAML
    h = hashlib.sha256(f'{pulls}:{seed}'.encode())
    h.update(TRUTH_YAML.read_bytes())
    for src in sorted(Path(core.__file__).parent.glob('*.py')):
        h.update(src.read_bytes())
    return h.hexdigest()[:16]


def reference_campaign(pulls: int, seed: int, say=print, cache: Path = CACHE, scheduler: str | None = None) -> Path:
    """The reference campaign folder (DAQ export format), generated if the cache does not hold it: each pull is
    simulated and written on a Dask worker (force_tester_common.engine; ``scheduler`` as in map_pulls)."""
    from bag_tools.core.daq import write_campaign
    from force_tester_common.engine import Mapper
    from force_tester_sim.core.campaign import campaign_jobs, simulate_campaign_pull
    from force_tester_sim.core.params import TRUTH_YAML, load_rig
    key = cache_key(pulls, seed)
    folder = cache / f'reference_campaign_{key}'
    if (folder / 'campaign.yaml').is_file():
        return folder
    say(f'generating the reference campaign ({5 * pulls} pulls of 2 s at 50 kHz, truth rig, seed {seed}) '
        f'into {folder} ...')
    t0 = time.monotonic()
    mapper = Mapper(scheduler)
    for old in cache.glob('reference_campaign_*'):  # a stale campaign (older model or other size)
        shutil.rmtree(old, ignore_errors=True)
    cache.mkdir(parents=True, exist_ok=True)
    write_campaign(folder, campaign_jobs(load_rig(TRUTH_YAML), pulls=pulls, seed=seed), mapper=mapper,
                   produce=simulate_campaign_pull)
    rerun = f'; rerun after a worker died: {", ".join(mapper.retried)}' if mapper.retried else ''
    say(f'  done in {time.monotonic() - t0:.1f} s on {mapper.where}{rerun}')
    return folder


def reference_extension(pulls: int = REFERENCE_PULLS, seed: int = REFERENCE_SEED, say=print,
                        cache: Path = CACHE) -> Path:
    """extension.yaml that `./ft discover` finds on the reference campaign, discovered on first use and cached
    beside the campaign (keyed by the campaign and the discovery code)."""
    import force_discovery.core as core
    from force_discovery.core.pipeline import discover
    from force_tester_sim.core.params import load_rig
    folder = reference_campaign(pulls, seed, say, cache)
    h = hashlib.sha256(folder.name.encode())
    for src in sorted(Path(core.__file__).parent.glob('*.py')):
        h.update(src.read_bytes())
    out = cache / f'reference_discovery_{h.hexdigest()[:16]}'
    if (out / 'extension.yaml').is_file():
        return out / 'extension.yaml'
    say(f'discovering what the model of record gets wrong on {folder.name} (./ft discover; about two minutes, '
        f'once) ...')
    t0 = time.monotonic()
    for old in cache.glob('reference_discovery_*'):   # stale: another campaign or older discovery code
        shutil.rmtree(old, ignore_errors=True)
    report = discover(folder, load_rig(), out)   # streamed from the folder: bounded memory
    say(f'  done in {time.monotonic() - t0:.1f} s: {", ".join(c["name"] for c in report["causes"]) or "none"}')
    return out / 'extension.yaml'


def plot_top_speed(result: dict, path) -> bool:
    """Save velocity, current and power vs time as a PNG. ``result``: a top_speed_study dict or a
    simulate_drive dict. Returns False (and writes nothing) when matplotlib is not importable."""
    rec = result.get('run', result)
    try:
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
    except ImportError:
        return False
    t = rec['time_s']
    fig, ax = plt.subplots(3, 1, sharex=True, figsize=(7, 8))
    ax[0].plot(t, rec['velocity_m_s'] / FT_M, label='velocity')
    ax[0].plot(t, rec['command_m_s'] / FT_M, '--', label='command')
    ax[0].set_ylabel('fps')
    ax[0].legend()
    ax[1].plot(t, rec['current_a'])
    ax[1].set_ylabel('current, A')
    ax[2].plot(t, rec['power_w'] / 1e3, label='V i')
    ax[2].plot(t, rec['mech_power_w'] / 1e3, label='F v')
    ax[2].set_ylabel('kW')
    ax[2].set_xlabel('time, s')
    ax[2].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return True


def _fail(exc) -> int:
    print(f'./ft thesis: error: {" ".join(str(exc).split())}', file=sys.stderr)
    return 2


def run(args) -> int:
    from force_tester_common.engine import EngineError, check_scheduler
    try:   # a bad address fails first, before the (slow) imports and the top-speed study
        if not args.no_campaign:
            check_scheduler(args.scheduler)
    except EngineError as exc:
        return _fail(exc)
    from bag_tools.core.errors import BagError
    from force_tester_sim.core.errors import SimError
    try:
        return _run(args)
    except (EngineError, BagError, SimError) as exc:
        return _fail(exc)


def _run(args) -> int:
    from force_tester_sim.core.params import load_rig
    from force_tester_sim.core.thesis import format_report, mass_sweep, top_speed_study
    say = lambda m: print(m, file=sys.stderr)
    rig = load_rig()
    study = top_speed_study(rig)
    sweep = mass_sweep(rig)
    print(format_report(study, sweep))
    plots = Path(args.plots)
    plots.mkdir(parents=True, exist_ok=True)
    if plot_top_speed(study, plots / 'top_speed.png'):
        print(f'plot: {plots / "top_speed.png"}')
    out = {'top_speed': {k: study[k] for k in ('peak_fps', 'plateau_fps', 'current_limit_hit', 'peak_power_kw',
                                               'distance_to_plateau_ft', 'plateau_cause')},
           'mass_sweep': [{k: m[k] for k in ('mass_kg', 'peak_fps', 'plateau_fps')} for m in sweep]}
    if not args.no_campaign:
        from bag_tools.core.daq import read_campaign
        from force_correction.core.campaign_stats import campaign_tables, format_tables
        folder = reference_campaign(args.pulls, args.seed, say, Path(args.cache), args.scheduler)
        tables = campaign_tables(read_campaign(folder).pulls)
        print()
        print(format_tables(tables, rig))
        print(f'campaign: {folder}')
        out['campaign'] = {'folder': str(folder), 'sets': [
            {k: t[k] for k in ('set', 'stationary_avg_lbf', 'a2_max_g', 'raw_diff_pct', 'ma_diff_pct',
                               'ma_filter_diff_pct')} for t in tables]}
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
        print(f'json: {args.json}')
    return 0
