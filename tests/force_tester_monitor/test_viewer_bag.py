"""Acceptance: `./ft view --bag` (issue 41, item 9) in headless Chromium, on a bag the real recorder wrote.

The sim, correction, validator and recorder run as separate processes over Fast DDS for two pulls (sets 1 and
3); the recorder is stopped with SIGINT, as Ctrl-C stops it, and closes its bag. The viewer serves that bag from
its own origin and opens it by URL (Studio's remote-file data source), as `./ft view --bag` prints it. The page
must then show: the force and acceleration plots drawn (pixels of each series' colour in the panel), the %
plot's OK pulls, the last score and the last set summary in their tables with the validator's numbers; no data
source problem, no page error, no request off the machine, nothing the server answered with an error, and
every byte-range request answered 206 Partial Content, no dialog over the app.
"""
from __future__ import annotations

import signal
import time

import pytest
from browser_page import Page, chromium_binary, panel, table_rows

from ft_cli.commands import view
from ft_cli.graph import Graph, ScoreCollector

pytestmark = pytest.mark.browser

SETS = (1, 3)
# each plot's series colours (layouts/bag.json) and whether it draws dots: a plot of every sample of a block
# draws one dot a sample, which Studio colours 30 % darker (HSL lightness, tinycolor's darken(30)); the % plot
# draws lines in the colours themselves
DRAWN = {pid: ([p['color'] for p in cfg['paths']], cfg['xAxisVal'] == 'timestamp')
         for pid, cfg in view.bag_layout('')['configById'].items() if pid.startswith('Plot!')}
# a plot is drawn when more pixels of its series' colours show than its legend's swatches have (64 px each) by
# DRAWN_PX (series that coincide, as the corrected and the stationary force do, hide each other: a plot, not a
# series, is checked)
SWATCH_PX = 64
DRAWN_PX = 300


def drawn_enough(drawn: dict) -> bool:
    return all(sum(counts) > SWATCH_PX * len(counts) + DRAWN_PX for counts in drawn.values())


def darker(colour: str, by: float = 0.30) -> str:
    """COLOUR (#rrggbb) with its HSL lightness lowered by BY, as Studio's plot colours a dot."""
    import colorsys
    h, lightness, s = colorsys.rgb_to_hls(*(int(colour[i:i + 2], 16) / 255 for i in (1, 3, 5)))
    r, g, b = colorsys.hls_to_rgb(h, max(lightness - by, 0.0), s)
    return '#' + ''.join(f'{round(c * 255):02x}' for c in (r, g, b))


def record(tmp_path, collector: ScoreCollector):
    """The bag the recorder writes of a live run of SETS, one pull each: its folder."""
    graph = Graph(tmp_path / 'logs')
    bag = tmp_path / 'bag'
    try:
        graph.start('force_correction', 'correction_node')
        graph.start('force_correction', 'validator_node')
        recorder = graph.start('bag_tools', 'recorder_node', {'bag_path': str(bag)})
        assert collector.wait_for_graph({'/force_corrected': 2, '/force': 3, '/pull_event': 2}, timeout=60)
        graph.start('force_tester_sim', 'sim_node', {'test_sets': str(list(SETS)), 'pulls_per_set': 1, 'seed': 3,
                                                      'wait_for_subscribers': 2})
        assert collector.wait(len(SETS), 180, alive=lambda: not graph.dead()), graph.tail('validator_node')
        assert collector.wait_recorder_caught_up(timeout=60), graph.tail('recorder_node')
        recorder.send_signal(signal.SIGINT)
        assert recorder.wait(30) == 0, graph.tail('recorder_node')
    finally:
        graph.stop()
    return bag


def pixels_of(image, box: dict, colour: str, tolerance: int = 40) -> int:
    """How many pixels inside BOX (CSS px of the screenshot) are within TOLERANCE of COLOUR (#rrggbb) per channel."""
    import numpy as np
    rgb = np.asarray(image.convert('RGB'), dtype=np.int16)
    x0, y0 = int(box['x']), int(box['y'])
    part = rgb[y0:y0 + int(box['height']), x0:x0 + int(box['width'])]
    want = np.array([int(colour[i:i + 2], 16) for i in (1, 3, 5)], dtype=np.int16)
    return int((np.abs(part - want) <= tolerance).all(axis=-1).sum())


def test_a_recorded_bag_opens_in_the_viewer_by_url(tmp_path, ros_domain):
    from PIL import Image
    chromium = chromium_binary()
    view.check_installed()
    collector = ScoreCollector()
    try:
        bag = record(tmp_path, collector)
        scores = collector.scores
    finally:
        collector.close()
    assert [s['test_set'] for s in scores] == list(SETS), scores
    site = view.bag_site(bag)
    assert site.namespace == '' and site.file.parent == bag
    server = view.serve('127.0.0.1', 0, site)
    page = None
    try:
        page = Page(view.bag_url('127.0.0.1', server.server_address[1], site), chromium)
        first = page.next(timeout=120)
        if first['kind'] == 'launch-failed':
            pytest.skip(f'Chromium ({chromium}) did not start: {first["error"]}')
        last = []

        def shown(state):
            last[:] = [state]
            ids = {p['id'] for p in state['panels']}
            return {'Table!bagsets', 'Tab!bagtabs'} <= ids and table_rows(state, 'Table!bagsets') and \
                table_rows(state, 'Tab!bagtabs')
        state = page.state_until(shown, 120)
        assert state is not None, (page.problems, page.errors, last and [p['text'][:200] for p in last[0]['panels']])
        # the plots fill in once Studio has read the whole bag (its blocks, in the background)
        screenshot = tmp_path / 'viewer_bag.png'
        deadline = time.monotonic() + 120
        while True:
            state = page.state_until(lambda s: True, 30)
            page.command(f'screenshot {screenshot}', 'screenshot')
            image = Image.open(screenshot)
            drawn = {pid: [pixels_of(image, panel(state, pid)['box'], darker(c) if dots else c) for c in colours]
                     for pid, (colours, dots) in DRAWN.items()}
            if drawn_enough(drawn) or time.monotonic() > deadline:
                break
        print(f'screenshot: {screenshot}')
        # every series of every plot is drawn
        assert drawn_enough(drawn), drawn
        # the tables: the bag's last score and last set summary (the URL opens the bag at its last message)
        (score,) = table_rows(state, 'Tab!bagtabs')
        assert score['pull_id'] == str(scores[-1]['pull_id']) and score['test_set'] == str(SETS[-1]), score
        assert float(score['raw_diff_pct']) == pytest.approx(scores[-1]['raw_diff_pct'], rel=1e-3), score
        (summary,) = table_rows(state, 'Table!bagsets')
        assert (summary['test_set'], summary['pulls']) == (str(SETS[-1]), '1'), summary
        # read by byte ranges, each answered 206; nothing asked of the internet; no error anywhere
        assert page.ranged and all(status == 206 for _range, status in page.ranged), page.ranged
        assert page.problems == [] and page.errors == [], (page.problems, page.errors)
        assert page.external == [] and page.http_errors == [], (page.external, page.http_errors)
        # and no start-up dialog with online-only links over it (the URL names the data source)
        assert page.dialogs == set(), page.dialogs
    finally:
        if page is not None:
            page.close()
        server.shutdown()
