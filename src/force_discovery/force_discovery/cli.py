"""./ft discover DATA [--rig RIG.yaml] --out DIR: find what the model of record gets wrong in a campaign.

DATA is a campaign folder in the DAQ export format, a bag (converted to a temporary campaign first), or DAQ files
(a pull each, `lab/*.lvm --channels map.yaml`: no campaign.yaml needed).
Writes DIR/report.json, DIR/report.md (+ residuals.png when matplotlib is importable) and DIR/extension.yaml.
The pulls are streamed (bounded memory); the per-pull stages run on Dask (--scheduler, see
force_tester_common.engine). A pull whose file cannot be read is left out and named.
"""
from __future__ import annotations

import shutil
import sys
import tempfile
from pathlib import Path


def add_arguments(p):
    p.add_argument('data', metavar='DATA', nargs='+',
                   help='campaign folder (DAQ export format), a bag, or DAQ files (.lvm .mf4 .uff .tdms .csv: a '
                   'pull each; with --channels)')
    p.add_argument('--channels', metavar='MAP.yaml', default=None,
                   help='channel map of the DAQ files given as DATA (see src/bag_tools/README.md)')
    p.add_argument('--rig', metavar='RIG.yaml', default=None,
                   help='your rig YAML: departures are named against its nominal values and tolerances (default: '
                   'none; without a reference nothing is judged, with one the packaged nominal rig, ours)')
    p.add_argument('--out', metavar='DIR', required=True, help='output folder')
    p.add_argument('--no-plots', dest='plots', action='store_false',
                   help='write report.json, report.md and extension.yaml but no PNG plots (quicker; nothing '
                   'decided changes)')
    from force_tester_common.engine import add_scheduler_argument
    add_scheduler_argument(p)


def _error(msg: str) -> int:
    print(f'./ft discover: error: {" ".join(str(msg).split())}', file=sys.stderr)
    return 2


def main(args) -> int:
    from bag_tools.core.errors import BagError
    from force_tester_common.engine import EngineError, check_scheduler
    from force_tester_sim.core.errors import SimError

    from .core.errors import DiscoveryError
    tmp = None
    try:
        from force_tester_sim.core.params import load_rig

        from .core.pipeline import discover
        from .core.report import HELD_OUT
        rig = load_rig(args.rig) if args.rig else None
        items = [args.data] if isinstance(args.data, str) else list(args.data)
        data = Path(items[0])
        for item in items:
            if not Path(item).exists():
                return _error(f'DATA {item!r} does not exist; expected a campaign folder, a bag or DAQ files')
        channels = getattr(args, 'channels', None)
        files = len(items) > 1 or channels is not None or data.is_file()
        if files and any(Path(i).is_dir() for i in items):
            return _error(f'DATA {next(i for i in items if Path(i).is_dir())!r} is a folder; expected DAQ files '
                          'only (a campaign folder names its channel map in campaign.yaml, channels:)')
        scheduler = getattr(args, 'scheduler', None)
        check_scheduler(scheduler)   # an unreachable scheduler fails now, not after the bag is converted
        if files:
            from .core.source import file_refs
            folder = file_refs(items, channels)
        elif data.is_dir() and (data / 'campaign.yaml').is_file():
            folder = data
        else:
            from bag_tools.core.convert import bag_to_campaign
            tmp = Path(tempfile.mkdtemp(prefix='ft_discover_'))
            folder = bag_to_campaign(data, tmp / 'campaign')
        report = discover(folder, rig, Path(args.out), scheduler=scheduler, progress=_progress(), rig_file=args.rig,
                          plots=getattr(args, 'plots', True))
    except (BagError, DiscoveryError, SimError, EngineError) as exc:
        return _error(exc)
    except OSError as exc:
        print(f'./ft discover: error: I/O failure: {" ".join(str(exc).split())}', file=sys.stderr)
        return 1
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    for f in report.get('failed_pulls') or []:
        print(f'pull {f["pull"]} left out: {f["error"]}', file=sys.stderr)
    if report.get('retried_pulls'):
        print(f'rerun after a worker died: {", ".join(report["retried_pulls"])}', file=sys.stderr)
    if report['validation']['method'] != HELD_OUT:   # leave-one-out or per-pull: the free phases' estimates
        return print_reference_free(report, Path(args.out))
    if not report['fitted_pulls']:   # the data-quality screen left too few pulls: the report says which and why
        unread = f' ({len(report["failed_pulls"])} could not be read)' if report.get('failed_pulls') else ''
        return _error(f'{report["causes"][0]["evidence"]["value"]} usable pulls after the data-quality screen{unread}; '
                      f'expected at least {report["causes"][0]["evidence"]["threshold"]} '
                      f'(why: {Path(args.out) / "report.md"})')
    names = ', '.join(c['name'] for c in report['causes']) or 'none'
    if report['gain'] is None:
        print(f'cause: {report["cause"]} (named: {names}); {report["notes"][0] if report["notes"] else ""}')
    else:
        print(f'cause: {report["cause"]} (named: {names}); error {report["baseline_error"]:.4g} -> '
              f'{report["extended_error"]:.4g}, gain {report["gain"]:.3g}x')
    if report['within_tolerance'] or report['inconclusive']:
        print('within tolerance: ' + (', '.join(c['name'] for c in report['within_tolerance']) or '-')
              + '; inconclusive: ' + (', '.join(c['name'] for c in report['inconclusive']) or '-'))
    if report['data_quality']:
        print(f'data quality: {len(report["data_quality"])} defects or exclusions (report.md, Data quality)')
    print(f'report: {Path(args.out) / "report.md"}')
    return 0


def print_reference_free(report: dict, out: Path) -> int:
    """What the reference-free path says on the terminal (force_discovery/core/without_reference/)."""
    if not report['fitted_pulls']:
        return _error(f'no usable pulls without a reference ({len(report["excluded_pulls"])} excluded, '
                      f'{len(report["failed_pulls"])} unreadable); expected a record with an event and free phases '
                      f'(why: {out / "report.md"})')
    names = ', '.join(c['name'] for c in report['causes']) or 'none'
    why = f'no reference ({", ".join(report["absent"])} absent)' if report['absent'] else \
        f'{len(report["pulls"])} pull(s), too few for the analysis with a reference'
    print(f'{why}: cause: {report["cause"]} (named: {names}); '
          f'{report["validation"]["method"]} over {len(report["fitted_pulls"])} pull(s)')
    if not report['rig']['given']:
        print(report['rig']['what'])
    c = report.get('candidates') or {}
    if 'gain_mass_product' in c:
        g, d = c['gain_mass_product'], c['accel_delay']
        print(f'g m2 = {g["parameters"]["gain_mass_kg"]:.5g} kg, accelerometer delay '
              f'{1e6 * d["parameters"]["delay_s"]:.3g} us' + ('; modes: ' + ', '.join(
                  f'{m["frequency_hz"]:.1f} Hz' for m in report['modes'][:3]) if report.get('modes') else ''))
        from .core.without_reference.report import readings
        for line in readings(c):
            print(line)
    if 'moving_cell_gain' in c:
        print(f'with the stationary cell: g = {c["moving_cell_gain"]["parameters"]["gain"]:.5g}, m2 = '
              f'{c["effective_mass"]["parameters"]["mass_kg"]:.5g} kg')
    print('not identifiable: ' + '; '.join(f'{q["quantity"]} ({q["reason"].split(":")[0]})'
                                           for q in report['not_identifiable']))
    if report.get('indicated'):
        print('indicated (too few pulls to name): ' + ', '.join(x['name'] for x in report['indicated']))
    if report['data_quality'] or report['excluded_pulls']:
        print(f'data quality: {len(report["data_quality"])} defects, {len(report["excluded_pulls"])} pulls '
              'excluded (report.md, Data quality)')
    print(f'report: {out / "report.md"}')
    return 0


def _progress():
    """progress(stage, done, total) on one terminal line of stderr (nothing when stderr is not a terminal)."""
    if not sys.stderr.isatty():
        return None

    def show(stage, done, total):
        end = '\n' if stage == 'held-out' and done == total else ''
        print(f'\r./ft discover: {stage} {done}/{total} pulls   ', end=end, file=sys.stderr, flush=True)
    return show


def cli(argv=None) -> int:
    """The `discover` console script (`ros2 run force_discovery discover DATA --out DIR`)."""
    import argparse
    ap = argparse.ArgumentParser(prog='./ft discover', description=__doc__.split('\n\n')[0])
    add_arguments(ap)
    return main(ap.parse_args(argv))


if __name__ == '__main__':
    sys.exit(cli())
