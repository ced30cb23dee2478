"""./ft demo: the live graph over DDS, one pull of each test set, recorded to an MCAP bag.

Starts the correction, validator and recorder nodes and then the sim node as separate
processes (exactly what `./ft run PKG EXE` starts), collects the validator's /pull_score
messages in this process, stops everything with SIGINT (the recorder then closes the bag) and
prints a per-set table. Beside the thesis's m*a and m*a + MA, a second correction and validator
pair (under /extension/...) corrects with the extension that `./ft discover` found on the cached
reference campaign: the thesis's method and what discovery adds, in one table.
"""
from __future__ import annotations

import json
import os
import queue
import shutil
import signal
import sys
import threading
import time
from pathlib import Path

from force_tester_common.core.channels import (
    CORRECTED_TYPE,
    PULL_EVENT_TOPIC,
    PULL_SCORE_LATEST_TOPIC,
    PULL_SCORE_TOPIC,
    SET_SUMMARY_TOPIC,
)
from force_tester_common.core.correction import WINDOW
from force_tester_common.core.units import LBF_N

from ..graph import Graph, ScoreCollector
from ..paths import RUNS, executable
from ..peak_inputs import validator_params

CORRECTED_TOPIC = CORRECTED_TYPE[1][0]
EXT_NS = '/extension'   # the extension pair's topics: /extension/force_corrected, /extension/pull_score, ...
EXT_SCORE_TOPIC = EXT_NS + PULL_SCORE_TOPIC
EXT_CORRECTION = 'correction_extension'   # the extension pair's node names (graph.launch.xml names them alike)
EXT_VALIDATOR = 'validator_extension'
GRAPH_UP_S = 120.0   # how long the nodes may take to subscribe before the sim starts


def add_arguments(p):
    p.add_argument('--sets', nargs='+', type=int, default=[1, 2, 3, 4, 5], metavar='SET',
                   help='test sets to run (thesis Table 4; default: 1 2 3 4 5)')
    p.add_argument('--pulls', type=int, default=1, help='pulls per set (default 1)')
    p.add_argument('--seed', type=int, default=0, help='seed of the scatter and the noise (default 0)')
    p.add_argument('--rate', type=float, default=1.0, help='sim pace, real-time factor (default 1.0)')
    p.add_argument('--rig', default='truth', metavar='RIG',
                   help="'truth' (default: the reference rig, which departs from the datasheet like the thesis's "
                        "real rig, with coupons at their measured levels), 'nominal' (the datasheet rig, coupons "
                        "at their rating) or a rig YAML file")
    p.add_argument('--out', default=str(RUNS / 'demo'),
                   help='output folder: bag/, scores.json, logs/ (default runs/demo; replaced)')
    p.add_argument('--timeout', type=float, default=120.0, help='give up after this many seconds')
    p.add_argument('--extension', default='auto', metavar='FILE',
                   help="extension.yaml for the extension column: 'auto' (default: what ./ft discover finds on the "
                        "reference campaign of ./ft thesis, discovered once and cached under runs/cache), 'none' "
                        "(no column), or a file")
    p.add_argument('--monitor', action='store_true',
                   help='watch it live: also run the monitor node (Foxglove WebSocket on ws://127.0.0.1:8765, '
                        '/monitor/* topics) and show the terminal scoreboard (./ft monitor) while the demo runs')


def format_table(scores: list) -> str:
    """Per-set means; when the scores carry the extension pair's ('extension'), its corrected peak and % difference
    as two more columns."""
    ext = any(sc.get('extension') for sc in scores)
    head = (f"{'set':>3} {'pulls':>5} {'stationary':>11} {'raw moving':>11} {'m*a corr.':>10} {f'+ MA({WINDOW})':>10}"
            + (f" {'ext + m*a':>10}" if ext else '')
            + f" {'diff raw':>9} {'diff m*a':>9} {'diff MA':>8}" + (f" {'diff ext':>9}" if ext else '')
            + f" {'U m*a':>7}" + (f" {'U ext':>7}" if ext else '') + '\n'
            + f"{'':>3} {'':>5} {'peak lbf':>11} {'peak lbf':>11} {'peak lbf':>10} {'peak lbf':>10}"
            + (f" {'peak lbf':>10}" if ext else '') + f" {'%':>9} {'%':>9} {'%':>8}" + (f" {'%':>9}" if ext else '')
            + f" {'lbf':>7}" + (f" {'lbf':>7}" if ext else ''))
    rows = [head, '-' * (120 if ext else 92)]
    for s in sorted({sc['test_set'] for sc in scores}):
        group = [sc for sc in scores if sc['test_set'] == s]
        ext_group = [sc['extension'] for sc in group if sc.get('extension')]

        def mean(k, group=group):
            return sum(g[k] for g in group) / len(group) if group else float('nan')
        rows.append(f"{s:>3} {len(group):>5} {mean('stationary_peak_n') / LBF_N:>11.1f} "
                    f"{mean('raw_peak_n') / LBF_N:>11.1f} {mean('corrected_peak_n') / LBF_N:>10.1f} "
                    f"{mean('filtered_peak_n') / LBF_N:>10.1f} "
                    + (f"{mean('corrected_peak_n', ext_group) / LBF_N:>10.1f} " if ext else '')
                    + f"{mean('raw_diff_pct'):>9.1f} {mean('corrected_diff_pct'):>9.1f} "
                    + f"{mean('filtered_diff_pct'):>8.1f}"
                    + (f" {mean('corrected_diff_pct', ext_group):>9.1f}" if ext else '')
                    + f" {mean('corrected_peak_u_n') / LBF_N:>7.1f}"
                    + (f" {mean('corrected_peak_u_n', ext_group) / LBF_N:>7.1f}" if ext else ''))
    dropped = sum(sc['dropped_blocks'] for sc in scores)
    rows.append(f'% difference is thesis eq 1 at the peaks: |F_stat - F| / F_stat; dropped blocks: {dropped}')
    rows.append('U m*a' + (', U ext' if ext else '') + ': the expanded uncertainty (k = 2) of that corrected peak, '
                'mean over the pulls: peak +/- U')
    return '\n'.join(rows)


def extension_args(extension: Path) -> dict:
    """Graph.start arguments of the extension pair: a second correction node with ``extension`` and a second
    validator, their topics remapped under EXT_NS (node names too, so their parameters and logs stay apart). The
    validator follows the extension's correction (``correction_node``): its parameter changes mark the extension's
    pulls RECONFIGURED, the plain correction's do not."""
    def remap(*topics):   # relative rules, so that the pair works under a rig's namespace too (graph.launch.xml)
        return [a for topic in topics for a in ('-r', f'{topic.lstrip("/")}:={EXT_NS.lstrip("/")}{topic}')]
    return {'correction': dict(params={'extension_file': str(extension)}, key=EXT_CORRECTION,
                               extra=['--ros-args', '-r', f'__node:={EXT_CORRECTION}', *remap(CORRECTED_TOPIC)]),
            'validator': dict(key=EXT_VALIDATOR,
                              params={**validator_params(extension), 'correction_node': EXT_CORRECTION},
                              extra=['--ros-args', '-r', f'__node:={EXT_VALIDATOR}',
                                     *remap(CORRECTED_TOPIC, PULL_SCORE_TOPIC, PULL_SCORE_LATEST_TOPIC,
                                            SET_SUMMARY_TOPIC)])}


def resolve_extension(choice: str, say=print) -> Path | None:
    """--extension: None for 'none'; the reference campaign's discovered extension for 'auto'; else the file."""
    if choice == 'none':
        return None
    if choice == 'auto':
        from .thesis import reference_extension
        return reference_extension(say=say)
    path = Path(choice)
    if not path.is_file():
        raise RuntimeError(f'--extension {choice!r} is not a file; expected auto, none or an extension.yaml')
    return path.resolve()


def rig_params(rig: str) -> dict:
    """The sim node's rig_file and coupons parameters for --rig."""
    if rig == 'nominal':
        return {'rig_file': '', 'coupons': 'rated'}
    if rig == 'truth':
        from force_tester_sim.core.params import TRUTH_YAML
        return {'rig_file': str(TRUTH_YAML), 'coupons': 'measured'}
    return {'rig_file': str(Path(rig).resolve()), 'coupons': 'measured'}


def monitor_node_available() -> bool:
    """Whether the monitor node (package force_tester_monitor) is built."""
    try:
        executable('force_tester_monitor', 'monitor_node')
    except SystemExit:
        return False
    return True


def run_live(out: Path, sets, pulls: int, seed: int, rate: float, timeout: float, say=print,
             rig: str = 'truth', monitor: bool = False, extension: Path | None = None):
    """Run the graph, record out/bag, return the validator's scores (raises RuntimeError on failure).
    monitor: also run the monitor node (when it is built), first, so it sees every pull. extension: also run the
    extension pair (extension_args); each score then has its pull's score from that pair under 'extension'."""
    bag = out / 'bag'
    if bag.exists():
        shutil.rmtree(bag)
    out.mkdir(parents=True, exist_ok=True)
    graph = Graph(out / 'logs')
    collector = ScoreCollector(also=(EXT_SCORE_TOPIC,) if extension else ())
    expected = len(sets) * pulls
    pairs = 2 if extension else 1
    try:
        if monitor and monitor_node_available():
            graph.start('force_tester_monitor', 'monitor_node')
        graph.start('force_correction', 'correction_node')
        graph.start('force_correction', 'validator_node', validator_params())
        if extension:
            for exe, kw in extension_args(extension).items():
                graph.start('force_correction', f'{exe}_node', **kw)
        graph.start('bag_tools', 'recorder_node', {'bag_path': str(bag)})
        want = {CORRECTED_TOPIC: 2, '/force': 1 + 2 * pairs, PULL_EVENT_TOPIC: 1 + pairs}
        if extension:
            want[EXT_NS + CORRECTED_TOPIC] = 1
        # every node up before the first pull (on a loaded machine six processes take more than 30 s to start; a
        # pair that came up during pull 0 scored it from part of its blocks)
        if not collector.wait_for_graph(want, timeout=GRAPH_UP_S):
            short = {t: f'{collector.node.count_subscribers(t)}/{n}' for t, n in want.items()
                     if collector.node.count_subscribers(t) < n}
            raise RuntimeError(f'the graph was not up after {GRAPH_UP_S:.0f} s: subscribers (have/want) {short}, '
                               f'nodes that died {graph.dead()}')
        graph.start('force_tester_sim', 'sim_node', {
            'test_sets': '[' + ','.join(str(s) for s in sets) + ']', 'pulls_per_set': pulls, 'seed': seed,
            'rate': float(rate), 'wait_for_subscribers': want[PULL_EVENT_TOPIC],
            'wait_for_block_subscribers': want['/force'], 'exit_when_done': True, **rig_params(rig)})
        say(f'demo: {expected} pull(s) of 2 s at 50 kHz, sets {list(sets)}, {rig} rig; logs in {graph.log_dir}')
        ok = collector.wait(expected, timeout, alive=lambda: not graph.dead(),
                            progress=lambda sc: say(f"demo: scored pull {sc['pull_id'] + 1}/{expected} "
                                                    f"(set {sc['test_set']})"))
        if ok and not collector.wait_recorder_caught_up():  # it may lag behind on a busy machine
            say('demo: the recorder did not catch up within 30 s; stopping it anyway')
    finally:
        codes = graph.stop()
        collector.close()
    if not ok:
        dead = graph.dead() or ['sim_node']
        raise RuntimeError(f'only {len(collector.scores)} of {expected} pulls were scored; '
                           f'last lines of {dead[0]}:\n{graph.tail(dead[0])}')
    if codes.get('recorder_node') not in (0, -signal.SIGINT) or not (bag / 'metadata.yaml').is_file():
        raise RuntimeError(f'the recorder did not close the bag cleanly (exit code {codes.get("recorder_node")}):\n'
                           f'{graph.tail("recorder_node")}')
    scores = sorted(collector.scores, key=lambda sc: sc['pull_id'])
    if extension:
        ext = {sc['pull_id']: sc for sc in collector.also_scores[EXT_SCORE_TOPIC]}
        scores = [{**sc, 'extension': ext.get(sc['pull_id'])} for sc in scores]
    return scores


def run_with_scoreboard(args, out: Path, extension: Path | None) -> list:
    """The demo on a worker thread, the scoreboard (./ft monitor's app) in the foreground until the
    demo is done; what the demo says is shown on the scoreboard's last line, then printed."""
    from .monitor import MonitorModel, RosFeed, make_app
    said, result = [], {}

    def work():
        try:
            result['scores'] = run_live(out, args.sets, args.pulls, args.seed, args.rate, args.timeout,
                                        say=said.append, rig=args.rig, monitor=True, extension=extension)
        except Exception as exc:  # noqa: BLE001 - reported after the scoreboard closes
            result['error'] = exc
    feed = queue.SimpleQueue()
    ros = RosFeed(feed)   # first, on the main thread (rclpy's signal handlers)
    worker = threading.Thread(target=work, name='ft-demo', daemon=True)
    worker.start()
    try:
        make_app()(MonitorModel(), feed, status=lambda: said[-1] if said else 'demo: starting the graph',
                   done=lambda: not worker.is_alive()).run()
    finally:
        ros.close()
    worker.join()
    for line in said:
        print(line, file=sys.stderr)
    if 'error' in result:
        raise result['error']
    return result['scores']


def run(args) -> int:
    out = Path(args.out)
    t0 = time.monotonic()
    say = lambda m: print(m, file=sys.stderr)
    if args.monitor and not monitor_node_available():
        say('demo: the monitor node (force_tester_monitor) is not built: the scoreboard only, no Foxglove')
    try:
        extension = resolve_extension(args.extension, say)
        if extension:
            say(f'demo: the extension column corrects with {os.path.relpath(extension)} (found by ./ft discover on '
                f'the reference campaign)' if args.extension == 'auto' else f'demo: the extension column corrects '
                f'with {extension}')
        if args.monitor and sys.stdout.isatty() and sys.stdin.isatty():
            scores = run_with_scoreboard(args, out, extension)
        else:
            if args.monitor:
                say('demo: not a terminal, so no scoreboard here: run ./ft monitor in a terminal to watch')
            scores = run_live(out, args.sets, args.pulls, args.seed, args.rate, args.timeout, say=say,
                              rig=args.rig, monitor=args.monitor, extension=extension)
    except RuntimeError as exc:
        print(f'ft demo: error: {exc}', file=sys.stderr)
        return 1
    (out / 'scores.json').write_text(json.dumps(scores, indent=1))
    print(format_table(scores))
    if extension:
        print(f'ext + m*a: the correction with {os.path.relpath(extension)} (the extension ./ft discover found), '
              f'then m2 a2')
    print(f'bag: {out / "bag"}  (./ft bag info {os.path.relpath(out / "bag")})   scores: {out / "scores.json"}   '
          f'{time.monotonic() - t0:.1f} s')
    return 0
