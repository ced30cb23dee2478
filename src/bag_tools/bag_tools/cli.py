"""./ft bag COMMAND: record, play, inspect, convert and correct bags and DAQ campaigns.

bag_tools holds the I/O commands; `correct` and `plot` come from force_correction (see
build_parser). Every failure ends with one line on stderr, `./ft bag CMD: error: ...`, of at
most MAX_LINE characters (`./ft bag --verbose CMD ...` prints it whole), and a non-zero exit
code (2 for bad input, an unreachable --scheduler included, 1 for an I/O failure or an internal
error, 130 for Ctrl-C); never a traceback. import (and correct) on a campaign whose pull files
partly fail to read write the rest, name each failed pull in a warning and exit 2.
"""
from __future__ import annotations

import argparse
import math
import os
import re
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from .core.errors import BagError, one_line

#: Longest error or warning line printed without --verbose.
MAX_LINE = 200
_verbose = False


#: An absolute path in a message (up to a space, a quote, a colon or a comma).
_PATH = re.compile(r"(?<![\w.])/(?:[^\s'\":,/]+/)+[^\s'\":,/]+")


def _short_path(m: re.Match) -> str:
    """A long absolute path as '.../PARENT/NAME': the folders above say less than what follows the path."""
    path = m.group(0)
    return path if len(path) <= 40 else '.../' + '/'.join(path.rsplit('/', 2)[-2:])


def shorten(text: object, prefix: str = '') -> str:
    """prefix + text on one line, within MAX_LINE characters unless --verbose was given: long paths first lose
    their leading folders (the reason after them stays), then the line is cut."""
    line = prefix + one_line(text)
    if _verbose or len(line) <= MAX_LINE:
        return line
    line = _PATH.sub(_short_path, line)
    if len(line) <= MAX_LINE:
        return line
    tail = ' ... (--verbose: whole message)'
    return line[:MAX_LINE - len(tail)] + tail


@dataclass(frozen=True)
class Command:
    """A subcommand of ./ft bag contributed by another package: its parser set-up, what runs it
    and the exception types that mean bad input (exit 2)."""

    name: str
    help: str
    description: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]
    errors: tuple = ()

    def add_to(self, sub, chosen: str | None = None) -> None:
        p = _command(sub, self.name, self.help, chosen, description=self.description)
        if p is not None:
            self.add_arguments(p)
            p.set_defaults(func=self.run)


class _Parser(argparse.ArgumentParser):
    """argparse that reports a usage error in one line."""

    def error(self, message):
        self.exit(2, f'{self.prog}: error: {one_line(message)} (see {self.prog} --help)\n')


class Progress:
    """A single self-overwriting stderr line; silent when stderr is not a terminal."""

    def __init__(self, label: str, unit: str = '') -> None:
        self.label, self.unit = label, unit
        self.enabled = sys.stderr.isatty()
        self.t0 = time.monotonic()
        self.shown = False

    def __call__(self, done: int, total: int) -> None:
        if not self.enabled or not total:
            return
        frac = min(1.0, done / total)
        bar = '#' * int(frac * 30)
        sys.stderr.write(f'\r{self.label} [{bar:<30}] {done}/{total} {self.unit} '
                         f'{time.monotonic() - self.t0:.1f} s')
        sys.stderr.flush()
        self.shown = True

    def close(self) -> None:
        if self.shown:
            sys.stderr.write('\n')
            self.shown = False


def warn(cmd: str, warnings) -> None:
    for w in warnings:
        print(shorten(w, f'./ft bag {cmd}: warning: '), file=sys.stderr)


# --------------------------------------------------------------------------- commands
def cmd_info(args) -> int:
    from .core.info import bag_info, format_info
    print(format_info(bag_info(args.bag)))
    return 0


def cmd_play(args) -> int:
    from .player import run
    return run(args, args.ros_args, prog='./ft bag play')


def cmd_record(args) -> int:
    """Run the recorder node in this process until Ctrl-C."""
    from force_tester_common.ros import spin_nodes

    from .recorder_node import DEFAULT_TOPICS, RecorderNode, split_description
    if os.path.exists(args.output):
        raise BagError(f'output {args.output!r} exists already; expected a new directory name')
    topics = args.topics or DEFAULT_TOPICS
    for flag, val in (('--max-size', args.max_size), ('--max-duration', args.max_duration)):
        if not 0 <= val <= 1e6:
            raise BagError(f'{flag} {val!r} out of range; expected 0 (no split) to 1e6')
    ros_args = ['--ros-args', '-p', f'bag_path:={args.output}', '-p', f'topics:={list(topics)!r}',
                '-p', f'max_bag_size_mb:={float(args.max_size)!r}',
                '-p', f'max_bag_duration_s:={float(args.max_duration)!r}']
    print(f'recording {", ".join(topics)} to {args.output}'
          f'{split_description(args.max_size, args.max_duration)}; Ctrl-C stops', file=sys.stderr)
    return spin_nodes(RecorderNode, args=['recorder', *ros_args])


def cmd_reindex(args) -> int:
    """Finish a bag an interrupted recording left (no metadata.yaml, no MCAP summary)."""
    from .core.reindex import format_report, reindex
    print(format_report(reindex(args.bag)))
    return 0


def engine_for(args):
    """The per-pull mapper of a command with --scheduler; a bad address fails here, before any work."""
    from force_tester_common.engine import Mapper, check_scheduler
    check_scheduler(args.scheduler)
    return Mapper(args.scheduler)


def report_engine(cmd: str, mapper, failed=()) -> int:
    """Warn of the pulls rerun after a worker died; the failed pulls (named in the warnings before)
    make exit code 2 with one error line."""
    warn(cmd, [f'pull {n!r} was run again: its worker died ({mapper.where})' for n in mapper.retried])
    if failed:
        print(shorten(f'{len(failed)} pull(s) failed and were left out (warnings above); first: '
                      f'{failed[0][0]}: {failed[0][1]}', f'./ft bag {cmd}: error: '), file=sys.stderr)
        return 2
    return 0


def cmd_export(args) -> int:
    mapper = engine_for(args)
    from .core.convert import bag_to_campaign
    from .core.daq import campaign_index
    warnings: list = []
    prog = Progress('export')
    try:
        out = bag_to_campaign(args.bag, args.dir, progress=prog, warnings=warnings, mapper=mapper)
    finally:
        prog.close()
        warn('export', warnings)
    _path, rate, _rig, entries = campaign_index(out)
    print(f'exported {len(entries)} pull(s) at {rate:g} Hz to {out}')
    return report_engine('export', mapper)


def file_campaign(src: str, args) -> tuple:
    """(Campaign, [(channel, source, file unit, how)]) of one DAQ file: one pull per record."""
    from .core.channel_map import ChannelMap, apply_map, load_channel_map, pairs_map
    from .core.daq import Campaign, DaqPull, check_channels, check_meta
    from .core.daqfiles import file_format, read_records
    suffix = file_format(src)
    if not os.path.isfile(src):
        raise BagError(f'DAQ file {src!r} does not exist')
    if args.map and args.channels:
        raise BagError(f'--map {" ".join(args.map)!r} and --channels {args.channels!r} both name the channels; '
                       'expected one of them')
    if args.map and suffix != '.tdms':
        raise BagError(f'--map applies to a .tdms source, not {src!r}; use --channels MAP.yaml')
    cmap = load_channel_map(args.channels) if args.channels else pairs_map(args.map)
    if args.rate is not None:
        cmap = ChannelMap('--rate', {}, (), args.rate) if cmap is None else \
            ChannelMap(cmap.path, cmap.specs, cmap.absent, cmap.sample_rate_hz or args.rate)
    warnings: list = []
    records = read_records(src)
    raws = [apply_map(rec, cmap, src if len(records) == 1 else f'{src} record {k + 1}')
            for k, rec in enumerate(records)]
    pulls, absent, rate = [], (), None
    used = raws[0][2]
    for k, (raw, absent, _used) in enumerate(raws):
        channels, rate = check_channels(raw, src, rate, warnings, absent)
        pid = args.pull_id if args.pull_id is not None or len(raws) == 1 else k + 1
        meta = check_meta({'file': os.path.basename(src) + (f'#{k + 1}' if len(raws) > 1 else ''),
                           'set': args.set, 'coupon_lbf': args.coupon_lbf, 'velocity_fps': args.velocity_fps,
                           'decel_g': args.decel_g, 'start_ns': args.start_ns if k == 0 else None,
                           'pull_id': pid}, src, k)
        pulls.append(DaqPull(meta, channels))
    return Campaign(Path(src).parent, rate, pulls, None, warnings, [], absent), used


def describe_campaign(camp, used=None) -> str:
    """What --dry-run prints: the channels (source, file unit, conversion, SI unit), the absent ones, the
    rate, the duration and the events found in the moving cell, per pull."""
    from force_tester_common.core.channels import CHANNELS
    from force_tester_common.core.events import event_spans
    from force_tester_common.core.units import CHANNEL_DIMENSION, SI_UNIT
    lines = [f'{len(camp.pulls)} pull(s) at {camp.sample_rate_hz:g} Hz']
    src = {ch: (s, u, how) for ch, s, u, how in (used or [])}
    present = [c for c in CHANNELS[1:] if any(c in p.channels for p in camp.pulls)]
    lines.append('channels:')
    for c in present:
        s, u, how = src.get(c, (c, None, ''))
        frm = f' <- {s!r}' + (f' in {u}' if u else '') + (f', {how.strip()}' if how.strip() else '')
        lines.append(f'  {c} [{SI_UNIT[CHANNEL_DIMENSION[c]]}]{frm if s != c or u or how else ""}')
    if camp.absent:
        lines.append(f'absent: {", ".join(camp.absent)}')
    total = 0
    for p in camp.pulls:
        n = len(p.channels['time_s'])
        ev = len(event_spans(p.channels['force_moving_n'], camp.sample_rate_hz))
        total += ev
        lines.append(f'  {p.meta["file"]}: {n} samples, {n / camp.sample_rate_hz:.6g} s, {ev} event(s)')
    lines.append(f'duration {sum(len(p.channels["time_s"]) for p in camp.pulls) / camp.sample_rate_hz:.6g} s, '
                 f'{total} event(s)')
    return '\n'.join(lines)


def cmd_import(args) -> int:
    mapper = engine_for(args)
    from .core.channel_map import load_channel_map
    from .core.convert import campaign_to_bag
    from .core.daq import read_campaign
    warnings: list = []
    src = args.src
    used = None
    if args.init_map:
        return init_map(args)
    if not os.path.isdir(src):
        src, used = file_campaign(src, args)
    elif args.map:
        raise BagError('--map applies to a .tdms source; a campaign folder maps its TDMS '
                       "files with a 'map:' entry per pull in campaign.yaml")
    elif args.channels or args.dry_run:
        cmap = load_channel_map(args.channels) if args.channels else None
        src = read_campaign(src, mapper=mapper if not args.dry_run else None, skip_failed=not args.dry_run,
                            channel_map=cmap)
    if args.dry_run:
        warn('import', src.warnings)
        print(describe_campaign(src, used))
        return 0
    if args.bag is None:
        raise BagError('import needs BAG, the bag directory to create (or --dry-run)')
    prog = Progress('import', 'pulls')
    info: dict = {}
    try:   # a folder's pulls are read on the engine's workers and written as they come, in order
        out = campaign_to_bag(src, args.bag, block_size=args.block_size, progress=prog,
                              warnings=warnings, mapper=mapper, skip_failed=True, info=info)
    finally:
        prog.close()
        warn('import', warnings)
    print(f'imported {info["pulls"]} pull(s) at {info["sample_rate_hz"]:g} Hz into {out}')
    return report_engine('import', mapper, info['failed'])


def init_map(args) -> int:
    """import FILE --init-map MAP.yaml: write a skeleton channel map of FILE (nothing is imported)."""
    from .core.channel_map import FILL_IN, skeleton_map
    from .core.daqfiles import file_format
    if os.path.isdir(args.src):
        raise BagError(f'--init-map applies to a DAQ file, not the folder {args.src!r}; expected e.g. '
                       'import lab/rec1.lvm --init-map lab/map.yaml')
    if args.bag is not None or args.channels or args.dry_run:
        raise BagError('--init-map writes the channel map only; expected no BAG, --channels or --dry-run '
                       '(import again with --channels MAP.yaml once it is filled in)')
    file_format(args.src)
    if not os.path.isfile(args.src):
        raise BagError(f'DAQ file {args.src!r} does not exist')
    out = Path(args.init_map)
    if out.exists():
        raise BagError(f'channel map {str(out)!r} exists already; expected a new file name (it is never overwritten)')
    text = skeleton_map(args.src)
    with open(out, 'x', encoding='utf-8') as fh:
        fh.write(text)
    todo = text.count(FILL_IN) - text.count(f'# range: {FILL_IN}') - text.count(f'Fill in every {FILL_IN}')
    print(f'wrote the channel map skeleton {out}: ' + (f'fill in its {todo} {FILL_IN}(s), check its guesses, then '
          if todo else 'check its guesses, then ') + f'./ft bag import {args.src} --channels {out} --dry-run')
    return 0


# --------------------------------------------------------------------------- parser
def positive_float(name):
    def conv(text):
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f'{name} {text!r} is not a number') from None
        if not math.isfinite(v) or v <= 0:
            raise argparse.ArgumentTypeError(f'{name} {text!r} must be a finite number > 0')
        return v
    return conv


def _command(sub, name: str, help_: str, chosen: str | None, **kwargs) -> argparse.ArgumentParser | None:
    """The subparser of command ``name``, or None when another command is ``chosen``: then ``name`` gets only its
    help line (what `./ft bag --help` lists), and what its options need is not imported."""
    if chosen is not None and name != chosen:
        sub.add_parser(name, help=help_)
        return None
    return sub.add_parser(name, help=help_, **kwargs)


def build_parser(extra: Sequence[Command] = (), chosen: str | None = None) -> argparse.ArgumentParser:
    """The ./ft bag parser: bag_tools' own commands plus ``extra`` ones from the packages above
    it (force_correction adds correct and plot), which bag_tools itself does not import. ``chosen``: the
    command about to run, the only one whose arguments are set up (None: every command's)."""
    from force_tester_common.engine import add_scheduler_argument
    p = _Parser(prog='./ft bag', description='Record, play, inspect, convert and correct '
                'rosbag2 bags (MCAP or sqlite3) and DAQ campaign folders (see '
                'src/bag_tools/README.md).')
    p.add_argument('-v', '--verbose', action='store_true',
                   help=f'print error and warning lines whole (default: cut at {MAX_LINE} '
                   'characters)')
    sub = p.add_subparsers(dest='command', required=True, metavar='COMMAND',
                           parser_class=_Parser)
    i = _command(sub, 'info', 'topics, types, counts, duration, sample rate, dropped blocks, pulls', chosen)
    if i is not None:
        i.add_argument('bag')
        i.set_defaults(func=cmd_info)
    pl = _command(sub, 'play', 'republish a bag with its original timing; topics of types '
                  'not installed are skipped (./ft bag play --help)', chosen)
    if pl is not None:
        from .core.playback import PLAY_DESCRIPTION, add_play_arguments
        pl.description = PLAY_DESCRIPTION
        add_play_arguments(pl)
        pl.set_defaults(func=cmd_play)
    r = _command(sub, 'record', 'record topics to a new MCAP bag until Ctrl-C', chosen)
    if r is not None:
        r.add_argument('-o', '--output', required=True, help='bag directory to create')
        r.add_argument('--max-size', type=float, default=0.0, metavar='MB',
                       help='split: start a new .mcap file in the bag once the current one holds '
                       'MB megabytes (1e6 bytes); 0 = no split (default)')
        r.add_argument('--max-duration', type=float, default=0.0, metavar='S',
                       help='split: start a new .mcap file once the current one spans S seconds; '
                       '0 = no split (default)')
        r.add_argument('topics', nargs='*', help='topics (default: every force tester topic)')
        r.set_defaults(func=cmd_record)
    ri = _command(sub, 'reindex', 'rebuild the MCAP summary and metadata.yaml of a bag an '
                  'interrupted recording left', chosen, description='Like `ros2 bag reindex`: '
                  'every message whose chunk reached the disk is kept; the torn tail is '
                  'cut off, the summary, footer and metadata.yaml are written.')
    if ri is not None:
        ri.add_argument('bag', help='rosbag2 directory')
        ri.set_defaults(func=cmd_reindex)

    e = _command(sub, 'export', 'bag -> DAQ campaign folder (CSV per pull + campaign.yaml)', chosen,
                 description='Cut the bag into pulls at its PullEvent START/END and write '
                 'one lossless CSV per pull plus campaign.yaml (stamps kept as start_ns).')
    if e is not None:
        e.add_argument('bag', help='rosbag2 directory')
        e.add_argument('dir', help='campaign folder to create (must not exist)')
        add_scheduler_argument(e)
        e.set_defaults(func=cmd_export)

    im = _command(sub, 'import', 'DAQ campaign folder or DAQ file (.csv .tdms .lvm .mf4 .uff) -> bag', chosen,
                  description='Write the block messages and PullEvents of a campaign '
                  '(or of one DAQ file: TDMS, LabVIEW LVM, ASAM MDF4, UFF 58, CSV; one pull per '
                  'record) into a new bag. A channel map (--channels) says which file channel is '
                  'which of ours, in which unit and sensitivity, which sign, and which are absent.')
    if im is not None:
        _import_arguments(im)

    for command in extra:
        command.add_to(sub, chosen)
    return p


def _import_arguments(im: argparse.ArgumentParser) -> None:
    from force_tester_common.engine import add_scheduler_argument

    from .core.daq import META_DEFAULTS
    im.add_argument('src', help='campaign folder (campaign.yaml) or a DAQ file')
    im.add_argument('bag', nargs='?', default=None, help='bag directory to create (must not exist)')
    im.add_argument('--channels', metavar='MAP.yaml', default=None,
                    help='channel map: file channel -> workspace channel, unit, sensitivity or scale, sign, '
                    'absent channels, sample rate (see src/bag_tools/README.md)')
    im.add_argument('--init-map', metavar='MAP.yaml', default=None,
                    help='write a skeleton channel map of the DAQ file (its channels, units, rate and duration, a '
                    'guess of which is which, FILL_IN where only you know) and stop; import nothing')
    im.add_argument('--dry-run', action='store_true',
                    help='read and convert, write nothing: print the channels, units, rate, duration and '
                    'events understood')
    im.add_argument('--block-size', type=int, default=50, help='samples per block (default 50)')
    add_scheduler_argument(im)
    tg = im.add_argument_group('DAQ file source (a pull per record)')
    tg.add_argument('--map', action='append', metavar='COLUMN=CHANNEL',
                    help="TDMS only: DAQ column <- TDMS channel ('Channel' or 'Group/Channel'); repeat")
    tg.add_argument('--rate', type=positive_float('--rate'), default=None,
                    help='sample rate, Hz, when the file gives none')
    tg.add_argument('--set', type=int, default=META_DEFAULTS['set'], help='test set (default 0: unknown)')
    tg.add_argument('--coupon-lbf', type=float, default=META_DEFAULTS['coupon_lbf'], help='(default 0: unknown)')
    tg.add_argument('--velocity-fps', type=float, default=META_DEFAULTS['velocity_fps'], help='(default 0: unknown)')
    tg.add_argument('--decel-g', type=float, default=META_DEFAULTS['decel_g'], help='(default 0: unknown)')
    tg.add_argument('--start-ns', type=int, default=None, help='stamp of the first sample')
    tg.add_argument('--pull-id', type=int, default=None)
    im.set_defaults(func=cmd_import)


def main(argv=None, extra: Sequence[Command] = ()) -> int:
    """Run one command. Bad input (BagError, or an extra command's own error type) exits 2, an
    I/O failure (disk full, permission) 1, Ctrl-C 130; each with one line on stderr.
    ROS arguments (`play BAG --ros-args -r ...`) go last and only to play."""
    global _verbose
    argv = list(sys.argv[1:] if argv is None else argv)
    ros_args: list = []
    if '--ros-args' in argv:
        cut = argv.index('--ros-args')
        argv, ros_args = argv[:cut], argv[cut:]
    parser = build_parser(extra, chosen=next((a for a in argv if not a.startswith('-')), None))
    args = parser.parse_args(argv)
    if ros_args and args.command != 'play':
        parser.error(f'--ros-args applies to play, not to {args.command}')
    args.ros_args = ros_args
    _verbose = args.verbose
    from force_tester_common.engine import EngineError
    input_errors = (BagError, EngineError, *(e for c in extra for e in c.errors))
    prefix = f'./ft bag {args.command}: error: '
    try:
        return args.func(args)
    except input_errors as exc:
        print(shorten(exc, prefix), file=sys.stderr)
        return 2
    except OSError as exc:
        print(shorten(exc, prefix + 'I/O failure: '), file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f'{prefix}interrupted; no partial output is left', file=sys.stderr)
        return 130
    except Exception as exc:  # noqa: BLE001 - one line, never a traceback
        print(shorten(exc, f'{prefix}internal error {type(exc).__name__}: '), file=sys.stderr)
        return 1


if __name__ == '__main__':
    sys.exit(main())
