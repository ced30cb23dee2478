"""The browser tests' driver (tools/viewer/drive.mjs) seen from Python: a Page is headless Chromium with a viewer
URL open, its reports read on a thread; the helpers read a page state's panels."""
from __future__ import annotations

import json
import queue
import re
import shutil
import subprocess
import threading
import time

import pytest

from ft_cli.commands import view

DRIVER = view.VIEWER / 'drive.mjs'
NUMBER = re.compile(r'^-?\d+(\.\d+)?(e[-+]?\d+)?$', re.I)


class Page:
    """The driver (tools/viewer/drive.mjs) with the viewer open: its reports, read on a thread."""

    def __init__(self, url: str, chromium: str, size=(1600, 1000)):
        node = shutil.which('node')
        assert node, 'node is not on PATH; the machine image provides Node.js 20'
        self.proc = subprocess.Popen([node, str(DRIVER), url, '--chromium', chromium,
                                      '--width', str(size[0]), '--height', str(size[1])], cwd=view.VIEWER,
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True)
        self.reports = queue.Queue()
        self.errors = []
        self.problems = []
        self.external = []
        self.http_errors = []
        self.ranged = []       # (Range header, status) of each request that asked for a byte range
        self.dialogs = set()   # the text of every dialog a state showed over the app
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self):
        for line in self.proc.stdout:
            if line.startswith('{'):
                self.reports.put(json.loads(line))
        self.reports.put({'kind': 'exit', 'code': self.proc.wait()})

    def next(self, timeout: float) -> dict:
        report = self.reports.get(timeout=timeout)
        if report['kind'] == 'page-error':
            self.errors.append(report['error'])
        elif report['kind'] == 'problem':
            self.problems.append(report['text'])
        elif report['kind'] == 'external-request':
            self.external.append(report['url'])
        elif report['kind'] == 'http-error':
            self.http_errors.append((report['status'], report['url']))
        elif report['kind'] == 'ranged':
            self.ranged.append((report['range'], report['status']))
        elif report['kind'] == 'state' and report.get('dialog'):
            self.dialogs.add(report['dialog'])
        return report

    def state_until(self, condition, timeout: float, spin=lambda: None) -> dict | None:
        """The first page state for which condition(state) holds, or None after timeout."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            spin()
            try:
                report = self.next(timeout=0.2)
            except queue.Empty:
                continue
            assert report['kind'] != 'exit', f'the driver exited ({report}): {self.proc.stderr.read()[-2000:]}'
            if report['kind'] == 'state' and condition(report):
                return report
        return None

    def command(self, line: str, kind: str, timeout: float = 30) -> dict:
        self.proc.stdin.write(line + '\n')
        self.proc.stdin.flush()
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            report = self.next(timeout=max(0.1, deadline - time.monotonic()))
            if report['kind'] == kind:
                return report
        raise AssertionError(f'no {kind} report within {timeout} s')

    def close(self):
        if self.proc.poll() is None:
            try:
                self.proc.stdin.write('quit\n')
                self.proc.stdin.flush()
                self.proc.wait(timeout=20)
            except (OSError, subprocess.TimeoutExpired):
                self.proc.kill()
                self.proc.wait()


def panel(state: dict, panel_id: str) -> dict:
    found = [p for p in state['panels'] if p['id'] == panel_id]
    assert found, (panel_id, [p['id'] for p in state['panels']])
    return found[0]


def legend_values(state: dict, panel_id: str) -> dict:
    """{series label: the value the legend shows} of a plot, for the series that show a number."""
    return {e['label']: float(e['value']) for e in panel(state, panel_id)['legend'] if NUMBER.match(e['value'])}


def table_rows(state: dict, panel_id: str) -> list:
    """The rows of a Table panel as {column: text}, by the header row's names."""
    table = panel(state, panel_id)['table']
    return [dict(zip(table[0], row)) for row in table[1:]] if table else []


def chromium_binary() -> str:
    found = shutil.which('chromium') or shutil.which('chromium-browser')
    if not found:
        pytest.skip("no Chromium on PATH: the set-up installs Debian's chromium (apt-get install chromium)")
    return found
