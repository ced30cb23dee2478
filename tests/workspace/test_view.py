"""./ft view's file server and command line, without a browser (the browser test is
tests/force_tester_monitor/test_viewer_browser.py)."""
import json
import re
import subprocess
import urllib.error
import urllib.request
from urllib.parse import parse_qs, urlsplit

import numpy as np
import pytest

from ft_cli.commands import view
from ft_cli.paths import ROOT


def _get(server, path: str) -> tuple:
    url = f'http://127.0.0.1:{server.server_address[1]}{path}'
    try:
        with urllib.request.urlopen(url, timeout=30) as r:
            return r.status, r.headers.get('Content-Type'), r.read()
    except urllib.error.HTTPError as e:
        return e.code, None, b''


@pytest.fixture
def server():
    view.check_installed()   # ./ft test installs tools/viewer's npm packages first
    s = view.serve('127.0.0.1', 0)
    yield s
    s.shutdown()


def test_the_server_serves_the_page_the_app_and_the_workspace_layout(server):
    status, _, body = _get(server, '/')
    assert status == 200 and b'viewer.js' in body and b'studio/index.js' in body
    status, _, body = _get(server, '/layout.json')
    assert status == 200 and json.loads(body) == json.loads(view.LAYOUT.read_text())
    status, kind, _ = _get(server, '/studio/index.js')
    assert status == 200 and 'javascript' in kind
    wasm = next(p.name for p in view.SITE['studio'].iterdir() if p.suffix == '.wasm')
    assert _get(server, f'/studio/{wasm}')[1] == 'application/wasm'
    assert _get(server, '/vendor/react.production.min.js')[0] == 200
    assert _get(server, '/nothing-here.js')[0] == 404
    # the page names its (empty) icon, so a browser does not ask for /favicon.ico, a 404, on every load
    assert b'<link rel="icon" href="data:,"' in _get(server, '/')[2]
    # and Studio starts without its "open data source" dialog, whose links are online-only
    assert '[AppSetting.SHOW_OPEN_DIALOG_ON_STARTUP]: false' in (view.VIEWER / 'app' / 'viewer.js').read_text()
    assert _get(server, '/../../etc/passwd')[0] == 404


def test_the_url_names_the_layout_and_the_monitor_in_studios_deep_link_parameters():
    query = parse_qs(urlsplit(view.url('10.0.0.5', 8080, 'ws://10.0.0.5:9000')).query)
    assert query == {'ds': ['foxglove-websocket'], 'ds.url': ['ws://10.0.0.5:9000'], 'layoutId': [view.LAYOUT_ID]}
    # the page gives the layout that id
    assert f'"{view.LAYOUT_ID}"' in (view.VIEWER / 'app' / 'viewer.js').read_text()


def test_a_monitor_that_is_not_a_websocket_url_is_one_readable_line():
    r = subprocess.run([str(ROOT / 'ft'), 'view', '--monitor', 'localhost:8765'], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [
        f"ft: error: --monitor 'localhost:8765': expected a ws:// URL such as ws://127.0.0.1:{view.MONITOR_PORT}"]


def test_served_to_the_lab_network_the_url_names_this_machine_and_its_monitor():
    """--host 0.0.0.0: the printed URL must work from another machine, so it names this machine's address
    (not loopback), for the viewer and for the monitor the browser connects to."""
    proc = subprocess.Popen([str(ROOT / 'ft'), 'view', '--host', '0.0.0.0', '--port', '0'], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        first = proc.stdout.readline()
        hint = proc.stdout.readline()
    finally:
        proc.terminate()
        proc.wait(timeout=30)
    address = view.lan_address()
    assert address not in ('127.0.0.1', 'localhost'), address
    link = urlsplit(first.split(' at ', 1)[1].strip())
    assert link.hostname == address, first
    assert parse_qs(link.query)['ds.url'] == [f'ws://{address}:{view.MONITOR_PORT}'], first
    assert 'host:=0.0.0.0' in hint, hint


# ---- ./ft view --bag (issue 41, item 9): the bag from the viewer's own origin, read by byte ranges

T0 = 1_795_000_000_123_456_789


def write_bag(path, topic: str = '/force', blocks: int = 20):
    """A bag of BLOCKS /force blocks (10 ms apart) and one /pull_score, written by bag_tools' writer: its folder."""
    from bag_tools.core import BagWriter
    from bag_tools.core.typestore import default_typestore
    from force_tester_common.core.channels import FORCE_TYPE, PULL_SCORE_TYPE
    store = default_typestore()
    Time, Header = store.types['builtin_interfaces/msg/Time'], store.types['std_msgs/msg/Header']

    def header(ns):
        return Header(stamp=Time(sec=ns // 10**9, nanosec=ns % 10**9), frame_id='')
    score = store.types[PULL_SCORE_TYPE](header=header(T0), **{**{f: 0.0 for f in (
        'stationary_peak_n', 'raw_peak_n', 'corrected_peak_n', 'filtered_peak_n', 'raw_diff_pct', 'corrected_diff_pct',
        'filtered_diff_pct', 'raw_rms_n', 'corrected_rms_n', 'filtered_rms_n', 'corrected_peak_u_n',
        'filtered_peak_u_n', 'coverage_factor')}, 'pull_id': 0, 'test_set': 1, 'dropped_blocks': 0, 'status': 0,
        'detail': ''})
    with BagWriter(path, store) as w:
        w.add_topic(topic, FORCE_TYPE)
        w.add_topic(topic.rsplit('/', 1)[0] + '/pull_score', PULL_SCORE_TYPE)
        for k in range(blocks):
            ns = T0 + k * 10_000_000
            block = store.types[FORCE_TYPE](header=header(ns), sample_rate_hz=50_000.0, seq=k,
                                            moving_n=np.full(500, float(k)), stationary_n=np.zeros(500))
            w.write(topic, ns, store.serialize_cdr(block, FORCE_TYPE))
        w.write(topic.rsplit('/', 1)[0] + '/pull_score', T0 + blocks * 10_000_000,
                store.serialize_cdr(score, PULL_SCORE_TYPE))
    return path


def _ranged(server, path: str, range_header: str | None) -> tuple:
    """(status, headers, body) of a GET with that Range header (None: none)."""
    import http.client
    conn = http.client.HTTPConnection('127.0.0.1', server.server_address[1], timeout=30)
    try:
        conn.request('GET', path, headers={'Range': range_header} if range_header else {})
        r = conn.getresponse()
        return r.status, dict(r.getheaders()), r.read()
    finally:
        conn.close()


@pytest.fixture
def bag_server(tmp_path):
    view.check_installed()
    site = view.bag_site(write_bag(tmp_path / 'bag'))
    s = view.serve('127.0.0.1', 0, site)
    yield s, site
    s.shutdown()


def test_the_bag_is_served_whole_and_by_byte_ranges(bag_server):
    server, site = bag_server
    data = site.file.read_bytes()
    size = len(data)
    path = f'{view.BAG_URL_PATH}{site.file.name}'
    # a plain GET (Studio's size probe): the whole file, saying that ranges are accepted
    status, headers, body = _ranged(server, path, None)
    assert (status, headers['Accept-Ranges'], int(headers['Content-Length']), body) == (200, 'bytes', size, data)
    for header, first, last in (('bytes=10-19', 10, 19), ('bytes=-16', size - 16, size - 1),
                                ('bytes=100-', 100, size - 1), (f'bytes=5-{10 * size}', 5, size - 1),
                                ('bytes=0-0', 0, 0), (f'bytes=-{10 * size}', 0, size - 1)):
        status, headers, body = _ranged(server, path, header)
        assert (status, headers['Content-Range'], body) == (206, f'bytes {first}-{last}/{size}',
                                                            data[first:last + 1]), header
        assert int(headers['Content-Length']) == last - first + 1
    # several ranges, or another unit: answered whole (a server may ignore Range, RFC 9110 14.2)
    for header in ('bytes=0-1,5-6', 'items=0-5'):
        assert _ranged(server, path, header)[0::2] == (200, data), header


def test_a_range_outside_the_bag_or_malformed_is_416(bag_server):
    server, site = bag_server
    size = site.file.stat().st_size
    path = f'{view.BAG_URL_PATH}{site.file.name}'
    for header in (f'bytes={size}-', f'bytes={size + 5}-{size + 9}', 'bytes=20-10', 'bytes=-0', 'bytes=abc',
                   'bytes=-', 'bytes=1-2-3'):
        status, headers, body = _ranged(server, path, header)
        assert (status, headers.get('Content-Range'), body) == (416, f'bytes */{size}', b''), header
    with pytest.raises(view.ViewerError, match="'bytes=20-10'.*0-99"):
        view.byte_range('bytes=20-10', 100)
    # the rest of the site is as without a bag, but for the layout: the bag's
    assert _ranged(server, '/nothing.mcap', None)[0] == 404
    assert json.loads(_ranged(server, '/layout.json', None)[2]) == view.bag_layout('')


def test_the_bag_url_opens_the_bag_at_its_last_message_with_the_bag_layout(tmp_path):
    site = view.bag_site(write_bag(tmp_path / 'bag'))
    query = parse_qs(urlsplit(view.bag_url('10.0.0.5', 8080, site)).query)
    assert query['ds'] == ['remote-file'] and query['layoutId'] == [view.LAYOUT_ID]
    assert query['ds.url'] == [f'http://10.0.0.5:8080{view.BAG_URL_PATH}{site.file.name}']
    # time=: RFC 3339 with nanoseconds, as Studio's fromRFC3339String reads it: the last message (the score)
    assert site.end_ns == T0 + 20 * 10_000_000
    assert query['time'] == ['2026-11-18T11:06:40.323456789Z']
    assert "new RemoteDataSourceFactory()" in (view.VIEWER / 'app' / 'viewer.js').read_text()


def test_a_namespaced_bag_gets_the_layout_in_its_namespace(tmp_path):
    site = view.bag_site(next(write_bag(tmp_path / 'bag', topic='/rig2/force').glob('*.mcap')))   # the file itself
    assert site.namespace == '/rig2'
    layout = view.bag_layout(site.namespace)
    paths = [p['value'] for cfg in layout['configById'].values() for p in cfg.get('paths', [])]
    paths += [cfg['topicPath'] for cfg in layout['configById'].values() if 'topicPath' in cfg]
    assert paths and all(p.startswith('/rig2/') for p in paths), paths
    assert '/rig2/force.stationary_n[:]' in paths


@pytest.mark.parametrize('what', ('missing', 'two files', 'not mcap', 'no force'))
def test_a_bag_the_viewer_cannot_open_is_one_readable_line(tmp_path, what):
    bag = tmp_path / 'bag'
    if what == 'two files':
        for i, folder in enumerate((bag, tmp_path / 'other')):
            write_bag(folder)
            next(folder.glob('*.mcap')).rename(bag / f'bag_{i}.mcap')
    elif what == 'not mcap':
        bag = tmp_path / 'bag.db3'
        bag.write_bytes(b'SQLite format 3\0')
    elif what == 'no force':
        bag = write_bag(bag, topic='/forces')
    expected = {'missing': 'no such file or folder', 'two files': 'found 2 (bag_0.mcap, bag_1.mcap): name one',
                'not mcap': 'expected an .mcap file', 'no force': 'on a .../force topic'}[what]
    with pytest.raises(view.ViewerError, match=re.escape(expected)):
        view.bag_site(bag)
    if what == 'missing':   # and the command: exit 2, one line
        r = subprocess.run([str(ROOT / 'ft'), 'view', '--bag', str(bag)], capture_output=True, text=True, timeout=120)
        assert r.returncode == 2 and r.stderr.strip().splitlines() == [
            f"ft: error: --bag {str(bag)!r}: no such file or folder; expected a rosbag2 folder or an .mcap file"]
