"""./ft discover DATA [--rig RIG.yaml] --out DIR: find what the model of record gets wrong in a campaign.

DATA is a campaign folder in the DAQ export format or a bag (converted to a temporary campaign first).
Writes DIR/report.json, DIR/report.md (+ residuals.png when matplotlib is importable) and DIR/extension.yaml.
"""
from __future__ import annotations

import shutil
import sys
import tempfile
from pathlib import Path


def add_arguments(p):
    p.add_argument('data', metavar='DATA', help='campaign folder (DAQ export format) or a bag')
    p.add_argument('--rig', metavar='RIG.yaml', default=None,
                   help='nominal rig YAML (default: the packaged nominal rig)')
    p.add_argument('--out', metavar='DIR', required=True, help='output folder')


def _error(msg: str) -> int:
    print(f'./ft discover: error: {" ".join(str(msg).split())}', file=sys.stderr)
    return 2


def main(args) -> int:
    from bag_tools.core.errors import BagError
    from force_tester_sim.core.errors import SimError

    from .core.errors import DiscoveryError
    tmp = None
    try:
        from bag_tools.core.daq import read_campaign
        from force_tester_sim.core.params import load_rig

        from .core.pipeline import discover
        rig = load_rig(args.rig)
        data = Path(args.data)
        if not data.exists():
            return _error(f'DATA {str(data)!r} does not exist; expected a campaign folder or a bag')
        if data.is_dir() and (data / 'campaign.yaml').is_file():
            folder = data
        else:
            from bag_tools.core.convert import bag_to_campaign
            tmp = Path(tempfile.mkdtemp(prefix='ft_discover_'))
            folder = bag_to_campaign(data, tmp / 'campaign')
        camp = read_campaign(folder)
        pulls = [(p.meta, p.channels) for p in camp.pulls]
        report = discover(pulls, rig, Path(args.out))
    except (BagError, DiscoveryError, SimError) as exc:
        return _error(exc)
    except OSError as exc:
        print(f'./ft discover: error: I/O failure: {" ".join(str(exc).split())}', file=sys.stderr)
        return 1
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    if not report['fitted_pulls']:   # the data-quality screen left too few pulls: the report says which and why
        return _error(f'{report["causes"][0]["evidence"]["value"]} usable pulls after the data-quality screen; '
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


def cli(argv=None) -> int:
    """The `discover` console script (`ros2 run force_discovery discover DATA --out DIR`)."""
    import argparse
    ap = argparse.ArgumentParser(prog='./ft discover', description=__doc__.split('\n\n')[0])
    add_arguments(ap)
    return main(ap.parse_args(argv))


if __name__ == '__main__':
    sys.exit(cli())
