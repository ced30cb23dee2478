"""The shipped Foxglove layout: installed under share/, and every topic and field it plots is one
the monitor serves (a renamed field would leave an empty panel, silently)."""
import json
import re

from force_tester_monitor.monitor_node import DERIVED, FORWARDED

from ft_cli.paths import INSTALL

LAYOUT = INSTALL / 'force_tester_monitor' / 'share' / 'force_tester_monitor' / 'layouts' / 'force_tester.json'


def paths_in(layout: dict) -> list:
    out = []
    for cfg in layout['configById'].values():
        out += [p['value'] for p in cfg.get('paths', [])]
        if 'xAxisPath' in cfg:
            out.append(cfg['xAxisPath']['value'])
        if 'topicPath' in cfg:
            out.append(cfg['topicPath'])
    return out


def test_layout_plots_only_what_the_monitor_serves():
    from rosbags.interfaces import Nodetype

    from bag_tools.core.typestore import default_typestore
    layout = json.loads(LAYOUT.read_text())
    kinds = {k.split('!')[0] for k in layout['configById']}
    assert {'Plot', 'Table', 'DiagnosticSummary', 'Parameters'} <= kinds
    types = {**{t: n for t, (n, _f) in FORWARDED.items()}, **{t: n for t, (n, _c) in DERIVED.items()}}
    store = default_typestore()
    paths = paths_in(layout)
    assert any(p.startswith('/monitor/force.') for p in paths) and any('/monitor/pull_trace.' in p for p in paths)
    for path in paths:
        topic = max((t for t in types if path == t or path.startswith(t + '.')), key=len)
        msg_type = types[topic]
        for field in (re.sub(r'\[.*\]$', '', f) for f in path[len(topic) + 1:].split('.') if f):
            # a field of a nested message (pulls[:].pull_id): walk into the element type
            defs = dict(store.fielddefs[msg_type][1])
            assert field in defs, (path, list(defs))
            kind, detail = defs[field]
            msg_type = detail[0][1] if kind == Nodetype.SEQUENCE and detail[0][0] == Nodetype.NAME else \
                detail if kind == Nodetype.NAME else None
