"""The Foxglove client of the tests (tools/foxglove_client, npm packages installed by ./ft) and the
monitor's port, read from its log."""
from __future__ import annotations

import json
import re
import shutil
import subprocess
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
CLIENT_DIR = ROOT / 'tools' / 'foxglove_client'
PORT_LINE = re.compile(r'Foxglove WebSocket at ws://127\.0\.0\.1:(\d+)')
LAYOUT = ROOT / 'src' / 'force_tester_monitor' / 'layouts' / 'force_tester.json'


def _strings(value):
    if isinstance(value, str):
        yield value
    elif isinstance(value, dict):
        for v in value.values():
            yield from _strings(v)
    elif isinstance(value, list):
        for v in value:
            yield from _strings(v)


def layout_topics(layout: dict, served) -> list:
    """The topics of ``served`` that the layout's panels read (a path is a topic, or a topic and
    '.field'): what the Foxglove app subscribes to with this layout open."""
    used = set()
    for text in _strings(layout['configById']):
        hits = [t for t in served if text == t or text.startswith(t + '.')]
        if hits:
            used.add(max(hits, key=len))
    return sorted(used)


def client_command(port: int, *args: str) -> list:
    """node client.mjs --url ws://127.0.0.1:PORT ARGS; fails (never skips) if ./ft has not set it up."""
    node = shutil.which('node')
    assert node, 'node is not on PATH; the machine image provides Node.js 20'
    assert (CLIENT_DIR / 'node_modules' / '@foxglove' / 'ws-protocol').is_dir(), \
        f'{CLIENT_DIR}/node_modules is missing: run the tests through ./ft test, which installs it (npm ci)'
    return [node, str(CLIENT_DIR / 'client.mjs'), '--url', f'ws://127.0.0.1:{port}', *args]


def lines(text: str) -> list:
    return [json.loads(line) for line in text.split('\n') if line.startswith('{')]


def monitor_port(log: Path, proc: subprocess.Popen, timeout: float = 60.0) -> int:
    """The port the monitor reports serving on (it was started with port:=0)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        m = PORT_LINE.search(log.read_text(errors='replace')) if log.exists() else None
        if m:
            return int(m.group(1))
        assert proc.poll() is None, log.read_text(errors='replace')
        time.sleep(0.1)
    raise AssertionError(f'the monitor did not report its port within {timeout} s:\n{log.read_text()}')
