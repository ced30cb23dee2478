"""`./ft bag correct` and `./ft bag plot`: the commands force_correction adds to bag_tools' CLI."""
from __future__ import annotations

import math

from bag_tools.cli import Command, Progress, engine_for, positive_float, report_engine, warn
from force_tester_common.core.correction import LOADED_FRACTION, MASS_KG, WINDOW
from force_tester_common.core.units import LBF_N
from force_tester_common.engine import add_scheduler_argument

from ..core.errors import CorrectionError
from ..core.params import CorrectionParams
from ..core.peak_uncertainty import PeakInputs


def format_summary(result) -> str:
    """Per-set table: set, pulls, mean stationary peak (lbf), mean +- std % diff."""
    def f(x, w=6, d=1):
        return f'{x:{w}.{d}f}' if isinstance(x, float) and math.isfinite(x) else ' ' * (w - 1) + '-'
    lines = ['set pulls  stationary   diff raw %      diff m*a %     diff m*a+MA %',
             '             peak lbf   mean    std    mean    std    mean    std',
             '-' * 70]
    for s in result.sets:
        lines.append(f"{s.set_id:>3} {s.pulls:>5}  {f(s.mean_stationary_peak_n / LBF_N, 10)}"
                     f" {f(s.raw_mean_pct)} {f(s.raw_std_pct)}"
                     f"  {f(s.corrected_mean_pct)} {f(s.corrected_std_pct)}"
                     f"  {f(s.filtered_mean_pct)} {f(s.filtered_std_pct)}")
    for s in result.sets:   # each set's corrected peak with its expanded uncertainty
        scores = [r.score for r in result.pulls if r.test_set == s.set_id]
        u = [x.corrected_peak_u_n for x in scores if math.isfinite(x.corrected_peak_u_n)]
        if u:
            peak = sum(x.corrected_peak_n for x in scores) / len(scores)
            lines.append(f"set {s.set_id}: corrected (m*a) peak {peak / LBF_N:.1f} lbf +/- "
                         f"{sum(u) / len(u) / LBF_N:.1f} lbf (k = {scores[0].coverage_factor:g}), mean over "
                         f"{len(scores)} pull(s)")
    p = result.params
    lines.append(f"m2 = {p.mass_kg:g} kg, window = {p.window}; % difference is thesis "
                 f"eq 1 at the peaks; std over pulls (ddof 1); NaN samples: "
                 f"{result.nan_samples}; dropped blocks: {result.dropped_blocks}")
    return '\n'.join(lines)


def peak_inputs_arg(text: str | None) -> PeakInputs:
    """--peak-u M,G,S,D as PeakInputs (CorrectionError naming the value when it is not four numbers)."""
    if text is None:
        return PeakInputs()
    try:
        values = [float(v) for v in text.split(',')]
    except ValueError:
        values = []
    if len(values) != 4:
        raise CorrectionError(f'--peak-u {text!r} is invalid; expected four numbers M,G,S,D')
    return PeakInputs(*values)


def _correction_arguments(p) -> None:
    p.add_argument('--mass-kg', type=positive_float('--mass-kg'), default=MASS_KG,
                   help=f'moving-side mass m2, kg (default {MASS_KG})')
    p.add_argument('--window', type=int, default=WINDOW,
                   help=f'moving average, samples (default {WINDOW})')


def _correct_arguments(p) -> None:
    p.add_argument('src', help='bag or campaign folder')
    p.add_argument('dst', help='output bag or campaign folder (must not exist)')
    _correction_arguments(p)
    p.add_argument('--extension', metavar='YAML', default=None,
                   help="extension.yaml of ./ft discover: undo its correction: section before m*a "
                        "(its mass_kg replaces --mass-kg)")
    p.add_argument('--loaded-fraction', type=float, default=LOADED_FRACTION,
                   help=f'RMS window: stationary > this x its peak (default {LOADED_FRACTION})')
    p.add_argument('--window-from-bandwidth', action='store_true',
                   help='choose the moving average from the bandwidth of the short events (impacts narrower '
                   'than a few windows) instead of --window; not the default')
    p.add_argument('--peak-u', metavar='M,G,S,D', default=None,
                   help="standard uncertainties (k = 1) of m2 (relative), the moving cell's gain (relative), the "
                        "accelerometer's sensitivity (relative) and lag (s), for each corrected peak's expanded "
                        "uncertainty, e.g. 0.01,0.005,0.01,2.9e-6 (the nominal rig's); default: the noise only")
    p.add_argument('--to', choices=('bag', 'campaign'), default=None,
                   help='output kind (default: the kind of SRC)')
    add_scheduler_argument(p)


def run_correct(args) -> int:
    mapper = engine_for(args)   # a bad address fails first
    from .pipeline import CorrectionSetup, correct
    setup = CorrectionSetup.build(args.mass_kg, args.window, args.extension,
                                  loaded_fraction=args.loaded_fraction,
                                  window_from_bandwidth=args.window_from_bandwidth,
                                  peak_inputs=peak_inputs_arg(args.peak_u))
    if setup.extension is not None and setup.extension.not_applied:
        warn('correct', [setup.extension.not_applied_warning()])
    prog = Progress('correct', 'messages')
    try:
        result = correct(args.src, args.dst, setup, to=args.to, progress=prog, mapper=mapper,
                         skip_failed=True)
    finally:
        prog.close()
    warn('correct', result.warnings)
    print(format_summary(result))
    print(f'written to {args.dst}')
    return report_engine('correct', mapper, mapper.failed)


def _plot_arguments(p) -> None:
    p.add_argument('src', help='bag or campaign folder')
    p.add_argument('--pull', type=int, required=True, help='pull number, 1-based, in time order')
    p.add_argument('--out', default=None, help='PNG to write (default pull_N.png)')
    p.add_argument('--si', action='store_true', help='SI units (N, m/s^2, m, m/s)')
    _correction_arguments(p)
    p.add_argument('--full', action='store_true', help='show the whole record, not just the pull')


def run_plot(args) -> int:
    from .plot import load_pull, plot_pull
    warnings: list = []
    pull, rate = load_pull(args.src, args.pull, warnings)
    warn('plot', warnings)
    out = args.out or f'pull_{args.pull}.png'
    plot_pull(pull, rate, out, si=args.si, params=CorrectionParams(args.mass_kg, args.window),
              full=args.full)
    print(f'wrote {out}')
    return 0


COMMANDS = (
    Command('correct', 'offline m*a correction + scoring (same core as the live nodes)',
            'Correct a bag or a campaign with the live correction core and score every pull; '
            'writes a new bag (adds /force_corrected, /pull_score, /set_summary) or a campaign '
            '(adds inertial_n, corrected_n, filtered_n columns and scores.json). Prints the '
            'per-set table.', _correct_arguments, run_correct, (CorrectionError,)),
    Command('plot', 'one pull -> PNG (forces, accelerometer, encoder)',
            'Plot one pull like thesis Figures 10-16: stationary vs moving vs corrected force, '
            'accelerometer, encoder position and velocity. lbf, g, ft and ft/s unless --si. '
            'Needs matplotlib.', _plot_arguments, run_plot, (CorrectionError,)),
)


def main(argv=None) -> int:
    """./ft bag with these commands added."""
    from bag_tools.cli import main as bag_main
    return bag_main(argv, COMMANDS)


if __name__ == '__main__':
    import sys
    sys.exit(main())
