"""./ft view: serve the local web viewer, with the workspace's layout, connected to the monitor (or on a bag).

The viewer is the open-source Foxglove Studio 1.48.0 (MPL-2.0), whose prebuilt app ships in the npm
package @foxglove/studio-base; tools/viewer holds the pinned npm packages and the few lines that
start the app (app/index.html, app/viewer.js). This command serves them, React's browser builds and
src/force_tester_monitor/layouts/force_tester.json from one port, with the standard library's HTTP
server. Nothing is fetched from the internet and no account is asked for. The URL it prints opens the
layout and the monitor's WebSocket through Studio's own deep-link parameters (ds, ds.url, layoutId).

`./ft view --bag PATH` serves a recorded bag instead (one MCAP file: PATH, or the one .mcap of a rosbag2 folder)
from the same origin, answering HTTP Range requests (206, or 416 for a range outside the file), as Studio's
remote-file data source reads it (ds=remote-file, ds.url=the file's URL; it probes the size with one plain GET it
aborts, then reads byte ranges). The layout is then layouts/bag.json, on the topics a bag holds (/force,
/force_corrected, /accel, /pull_score, /set_summary, /pull_event; a namespaced bag's, /rig2/force..., when the
bag was recorded under one), and the URL's time= opens it at its last message, so its tables show the last score
and summary.
"""
from __future__ import annotations

import contextlib
import email.utils
import functools
import json
import mimetypes
import re
import socket
import sys
import tempfile
import threading
from datetime import UTC, datetime
from http import HTTPStatus
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import NamedTuple
from urllib.parse import quote, urlsplit

from force_tester_monitor.core.params import PORT as MONITOR_PORT

from bag_tools.core.fastcdr import FastPathError
from bag_tools.core.mcapfile import read_summary
from force_tester_common.core.channels import FORCE_TYPE
from force_tester_common.core.clock import NS_PER_S

from ..paths import ROOT

VIEWER = ROOT / 'tools' / 'viewer'
MODULES = VIEWER / 'node_modules'
LAYOUT = ROOT / 'src' / 'force_tester_monitor' / 'layouts' / 'force_tester.json'
BAG_LAYOUT = LAYOUT.with_name('bag.json')   # the layout on what a bag holds (./ft view --bag)
BAG_URL_PATH = '/bag/'                       # where the bag's file is served: /bag/<its file name>
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


RANGE_SPEC = re.compile(r'\s*(\d*)\s*-\s*(\d*)\s*')


def byte_range(header: str | None, size: int) -> tuple[int, int] | None:
    """The first and last byte (inclusive) a Range header asks of a file of SIZE bytes, or None for the whole
    file: no Range, a unit other than bytes, or several ranges (which a server may answer whole, RFC 9110 14.2).
    A last byte past the end is the end. ViewerError (to be answered 416) for a malformed range or one that
    does not overlap the file."""
    if header is None:
        return None
    unit, _, spec = header.partition('=')
    if unit.strip().lower() != 'bytes' or ',' in spec:
        return None
    match = RANGE_SPEC.fullmatch(spec)
    if match is None or match.groups() == ('', ''):
        raise ViewerError(f'Range {header!r}: expected bytes=FIRST-LAST, bytes=FIRST- or bytes=-LENGTH')
    first, last = match.groups()
    if first == '':
        first, last = size - int(last), size - 1   # the last LENGTH bytes
        if last < 0 or first > last:
            raise ViewerError(f'Range {header!r}: no byte of the file\'s {size} is in it')
        return max(first, 0), last
    first, last = int(first), size - 1 if last == '' else min(int(last), size - 1)
    if first >= size or last < int(first):
        raise ViewerError(f'Range {header!r}: expected a range within the file\'s {size} bytes (0-{size - 1})')
    return first, last


class FileSlice:
    """Bytes FIRST..LAST of an open file, read as a file (for the handler's copyfile)."""

    def __init__(self, file, first: int, last: int):
        self.file, self.left = file, last - first + 1
        file.seek(first)

    def read(self, n: int = -1) -> bytes:
        data = self.file.read(self.left if n < 0 else min(n, self.left))
        self.left -= len(data)
        return data

    def close(self) -> None:
        self.file.close()


class ViewerHandler(SimpleHTTPRequestHandler):
    """The site's files, and the bag's file (the server's `bag`, a Path, at BAG_URL_PATH + its name) with byte
    ranges. Overrides the standard library's send_head (the bag's headers: 200, 206 or 416), copyfile (a reader
    that hangs up) and log_message (no access lines: a page load asks for about 90 files)."""

    def log_message(self, format, *args):
        pass

    def send_head(self):
        bag = getattr(self.server, 'bag', None)
        if bag is None or urlsplit(self.path).path != BAG_URL_PATH + bag.name:
            return super().send_head()
        file = bag.open('rb')
        size = bag.stat().st_size
        try:
            wanted = byte_range(self.headers.get('Range'), size)
        except ViewerError as exc:
            file.close()
            self.send_response(HTTPStatus.REQUESTED_RANGE_NOT_SATISFIABLE, str(exc))
            self.send_header('Content-Range', f'bytes */{size}')
            self.send_header('Content-Length', '0')
            self.end_headers()
            return None
        first, last = wanted if wanted is not None else (0, size - 1)
        if wanted is None:
            self.send_response(HTTPStatus.OK)
        else:
            self.send_response(HTTPStatus.PARTIAL_CONTENT)
            self.send_header('Content-Range', f'bytes {first}-{last}/{size}')
        self.send_header('Content-Type', 'application/octet-stream')
        self.send_header('Accept-Ranges', 'bytes')
        self.send_header('Content-Length', str(last - first + 1))
        self.send_header('Last-Modified', email.utils.formatdate(bag.stat().st_mtime, usegmt=True))
        self.send_header('Cache-Control', 'no-cache')
        self.end_headers()
        return FileSlice(file, first, last)

    def copyfile(self, source, outputfile):
        # Studio learns the bag's size from a plain GET it aborts once the headers are in: not an error
        with contextlib.suppress(BrokenPipeError, ConnectionResetError):
            super().copyfile(source, outputfile)


class BagSite(NamedTuple):
    """What ./ft view --bag serves: the MCAP file, the topics' namespace and the time of its last message."""
    file: Path
    namespace: str      # '' or '/rig2': where the bag's /force is
    end_ns: int


def bag_site(path: str | Path) -> BagSite:
    """The MCAP file of a bag (PATH itself, or the one .mcap file of a rosbag2 folder), the namespace of its force
    topic and its last message's time. ViewerError (one line) for anything else."""
    path = Path(path)
    if path.is_dir():
        files = sorted(path.glob('*.mcap'))
        if len(files) != 1:
            raise ViewerError(f'--bag {str(path)!r}: expected a rosbag2 folder with one .mcap file, found '
                              f'{len(files)}' + (f' ({", ".join(f.name for f in files)}): name one of them'
                                                 if files else ''))
        path = files[0]
    elif not path.is_file():
        raise ViewerError(f'--bag {str(path)!r}: no such file or folder; expected a rosbag2 folder or an .mcap file')
    if path.suffix != '.mcap':
        raise ViewerError(f'--bag {str(path)!r}: expected an .mcap file (rosbag2\'s MCAP storage)')
    try:
        summary = read_summary(path)
    except FastPathError as exc:
        raise ViewerError(f'--bag {str(path)!r}: {exc}; expected an indexed MCAP file (a bag whose recorder was '
                          f'killed: ./ft bag reindex BAG first)') from None
    schemas = {sid: s.name for sid, s in summary.schemas.items()}
    force = sorted(c.topic for c in summary.channels.values()
                   if schemas.get(c.schema_id) == FORCE_TYPE and c.topic.rsplit('/', 1)[-1] == 'force')
    end_ns = summary.statistics.message_end_time if summary.statistics else 0
    if not force or not end_ns:
        raise ViewerError(f'--bag {str(path)!r}: no {FORCE_TYPE} messages on a .../force topic; expected a bag '
                          f'the workspace recorded')
    return BagSite(path, force[0].rsplit('/', 1)[0], end_ns)


def bag_layout(namespace: str) -> dict:
    """layouts/bag.json with its topics in NAMESPACE ('' : as they are)."""
    layout = json.loads(BAG_LAYOUT.read_text())
    text = json.dumps(layout['configById'])
    layout['configById'] = json.loads(re.sub(r'"(topicPath|value)": "/', rf'"\1": "{namespace}/', text))
    return layout


def serve(host: str = HOST, port: int = PORT, bag: BagSite | None = None) -> ThreadingHTTPServer:
    """An HTTP server for the viewer on HOST:PORT (0: any free port), serving from a daemon thread; with BAG, the
    bag's file too and the bag layout. The site's folder (a temporary one) goes when the server object does."""
    check_installed()
    site = tempfile.TemporaryDirectory(prefix='ft-viewer-')
    make_site(Path(site.name))
    if bag is not None:
        (Path(site.name) / 'layout.json').unlink()
        (Path(site.name) / 'layout.json').write_text(json.dumps(bag_layout(bag.namespace)))
    server = ThreadingHTTPServer((host, port), functools.partial(ViewerHandler, directory=site.name))
    server.site = site
    server.bag = bag.file if bag is not None else None
    server.daemon_threads = True
    threading.Thread(target=server.serve_forever, name='viewer', daemon=True).start()
    return server


def url(host: str, port: int, monitor: str) -> str:
    """The viewer's address that opens the layout and connects to MONITOR (ws://HOST:PORT)."""
    return (f'http://{host}:{port}/?ds=foxglove-websocket&ds.url={quote(monitor, safe="")}'
            f'&layoutId={LAYOUT_ID}')


def bag_url(host: str, port: int, bag: BagSite) -> str:
    """The viewer's address that opens the bag layout on BAG, served at HOST:PORT, at its last message."""
    end = datetime.fromtimestamp(bag.end_ns // NS_PER_S, UTC).strftime('%Y-%m-%dT%H:%M:%S')
    file_url = f'http://{host}:{port}{BAG_URL_PATH}{quote(bag.file.name)}'
    return (f'http://{host}:{port}/?ds=remote-file&ds.url={quote(file_url, safe="")}&layoutId={LAYOUT_ID}'
            f'&time={end}.{bag.end_ns % NS_PER_S:09d}Z')


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
    p.add_argument('--bag', default=None, metavar='PATH',
                   help='open a recorded bag instead of the monitor: a rosbag2 folder of one .mcap file, or an '
                        '.mcap file; it is served from the viewer\'s own address (with HTTP Range requests) and '
                        'opened at its last message, with a layout on what a bag holds (/force, /force_corrected, '
                        '/accel, /pull_score, /set_summary, /pull_event; a namespaced bag\'s too)')


def run(args) -> int:
    if args.monitor is not None and not args.monitor.startswith(('ws://', 'wss://')):
        print(f'ft: error: --monitor {args.monitor!r}: expected a ws:// URL such as ws://127.0.0.1:{MONITOR_PORT}',
              file=sys.stderr)
        return 2
    bag = None
    if args.bag is not None:
        if args.monitor is not None:
            print('ft: error: --bag and --monitor: expected one of them (a bag, or the live monitor)', file=sys.stderr)
            return 2
        try:
            bag = bag_site(args.bag)
        except ViewerError as exc:
            print(f'ft: error: {exc}', file=sys.stderr)
            return 2
    try:
        server = serve(args.host, args.port, bag)
    except (ViewerError, OSError) as exc:
        print(f'ft: error: {exc}', file=sys.stderr)
        return 1
    host, port = server.server_address[:2]
    shown = shown_host(host)
    monitor = args.monitor or f'ws://{shown}:{MONITOR_PORT}'
    address = url(shown, port, monitor) if bag is None else bag_url(shown, port, bag)
    print(f'viewer (Foxglove Studio 1.48.0, MPL-2.0) at {address}', flush=True)
    if bag is not None:
        print(f'on the bag {bag.file}' + (f' (its topics under {bag.namespace})' if bag.namespace else ''),
              flush=True)
    elif shown != HOST and args.monitor is None:
        print(f'the browser connects to the monitor at {monitor}: start it with -p host:=0.0.0.0', flush=True)
    print('Ctrl-C stops it', flush=True)
    try:
        threading.Event().wait()
    except KeyboardInterrupt:
        pass
    finally:
        server.shutdown()
    return 0
