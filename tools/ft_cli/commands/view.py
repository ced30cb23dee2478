"""./ft view: serve the local web viewer, with the workspace's layout, connected to the monitor.

The viewer is the open-source Foxglove Studio 1.48.0 (MPL-2.0), whose prebuilt app ships in the npm
package @foxglove/studio-base; tools/viewer holds the pinned npm packages and the few lines that
start the app (app/index.html, app/viewer.js). This command serves them, React's browser builds and
src/force_tester_monitor/layouts/force_tester.json from one port, with the standard library's HTTP
server. Nothing is fetched from the internet and no account is asked for. The URL it prints opens the
layout and the monitor's WebSocket through Studio's own deep-link parameters (ds, ds.url, layoutId).
"""
from __future__ import annotations

import functools
import mimetypes
import socket
import sys
import tempfile
import threading
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import quote

from force_tester_monitor.core.params import PORT as MONITOR_PORT

from ..paths import ROOT

VIEWER = ROOT / 'tools' / 'viewer'
MODULES = VIEWER / 'node_modules'
LAYOUT = ROOT / 'src' / 'force_tester_monitor' / 'layouts' / 'force_tester.json'
LAYOUT_ID = 'force-tester'          # the id app/viewer.js gives the layout
HOST = '127.0.0.1'
PORT = 8080
# the site: what each URL path serves (a folder serves its files under its path)
SITE = {
    'index.html': VIEWER / 'app' / 'index.html',
    'viewer.js': VIEWER / 'app' / 'viewer.js',
    'layout.json': LAYOUT,
    'vendor/react.production.min.js': MODULES / 'react' / 'umd' / 'react.production.min.js',
    'vendor/react-dom.production.min.js': MODULES / 'react-dom' / 'umd' / 'react-dom.production.min.js',
    'studio': MODULES / '@foxglove' / 'studio-base' / 'assets',
}
mimetypes.add_type('application/wasm', '.wasm')   # so that the browser compiles the app's wasm as it streams in


class ViewerError(Exception):
    """The viewer cannot be served: what is missing and how to get it."""


def check_installed() -> None:
    missing = [str(p.relative_to(ROOT)) for p in SITE.values() if not p.exists()]
    if missing:
        raise ViewerError(f'the viewer is not installed: {missing[0]} is missing (./ft view installs it with '
                          f'npm ci in tools/viewer)')


def make_site(into: Path) -> None:
    """The site as a folder of symbolic links, for the standard library's file server."""
    for name, target in SITE.items():
        link = into / name
        link.parent.mkdir(parents=True, exist_ok=True)
        link.symlink_to(target)


def _no_access_log(handler, format, *args):
    """The file server's access lines are not printed: a page load asks for about 90 files."""


QuietHandler = type('QuietHandler', (SimpleHTTPRequestHandler,), {'log_message': _no_access_log})


def serve(host: str = HOST, port: int = PORT) -> ThreadingHTTPServer:
    """An HTTP server for the viewer on HOST:PORT (0: any free port), serving from a daemon thread. The site's
    folder (a temporary one) goes when the server object does."""
    check_installed()
    site = tempfile.TemporaryDirectory(prefix='ft-viewer-')
    make_site(Path(site.name))
    server = ThreadingHTTPServer((host, port), functools.partial(QuietHandler, directory=site.name))
    server.site = site
    server.daemon_threads = True
    threading.Thread(target=server.serve_forever, name='viewer', daemon=True).start()
    return server


def url(host: str, port: int, monitor: str) -> str:
    """The viewer's address that opens the layout and connects to MONITOR (ws://HOST:PORT)."""
    return (f'http://{host}:{port}/?ds=foxglove-websocket&ds.url={quote(monitor, safe="")}'
            f'&layoutId={LAYOUT_ID}')


def lan_address() -> str:
    """This machine's address on its default route, as other machines of the lab network reach it (a UDP socket
    is connected to a documentation address to pick the interface; no packet is sent), else its host name."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.connect(('192.0.2.1', 9))
            return s.getsockname()[0]
        except OSError:
            return socket.gethostname()


def shown_host(host: str) -> str:
    """The address a browser uses to reach a server bound to HOST."""
    return lan_address() if host in ('0.0.0.0', '::') else host


def add_arguments(p):
    p.add_argument('--host', default=HOST,
                   help=f'address to serve on (default {HOST}; 0.0.0.0 for every interface: browsers on the lab '
                        'network, and the monitor is looked for at this machine\'s address)')
    p.add_argument('--port', type=int, default=PORT, help=f'HTTP port to serve on (default {PORT}; 0: any free port)')
    p.add_argument('--monitor', default=None, metavar='URL',
                   help="the monitor's Foxglove WebSocket, as the browser reaches it "
                        f'(default ws://HOST:{MONITOR_PORT}, HOST as the viewer is reached)')


def run(args) -> int:
    if args.monitor is not None and not args.monitor.startswith(('ws://', 'wss://')):
        print(f'ft: error: --monitor {args.monitor!r}: expected a ws:// URL such as ws://127.0.0.1:{MONITOR_PORT}',
              file=sys.stderr)
        return 2
    try:
        server = serve(args.host, args.port)
    except (ViewerError, OSError) as exc:
        print(f'ft: error: {exc}', file=sys.stderr)
        return 1
    host, port = server.server_address[:2]
    shown = shown_host(host)
    monitor = args.monitor or f'ws://{shown}:{MONITOR_PORT}'
    print(f'viewer (Foxglove Studio 1.48.0, MPL-2.0) at {url(shown, port, monitor)}', flush=True)
    if shown != HOST and args.monitor is None:
        print(f'the browser connects to the monitor at {monitor}: start it with -p host:=0.0.0.0', flush=True)
    print('Ctrl-C stops it', flush=True)
    try:
        threading.Event().wait()
    except KeyboardInterrupt:
        pass
    finally:
        server.shutdown()
    return 0
