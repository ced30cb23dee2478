"""./ft view's file server and command line, without a browser (the browser test is
tests/force_tester_monitor/test_viewer_browser.py)."""
import json
import subprocess
import urllib.error
import urllib.request
from urllib.parse import parse_qs, urlsplit

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
