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


def check_fields(paths: list, types: dict) -> None:
    """Each message path names a topic of TYPES ({topic: type}) and, field by field, fields of its type."""
    from rosbags.interfaces import Nodetype

    from bag_tools.core.typestore import default_typestore
    store = default_typestore()
    for path in paths:
        topic = max((t for t in types if path == t or path.startswith((t + '.', t + '{'))), key=len)
        msg_type = types[topic]
        rest = re.sub(r'^\{[^}]*\}', '', path[len(topic):])   # a filter on the message itself
        for field in (re.sub(r'(\[.*\])?(\{.*\})?$', '', f) for f in rest.split('.') if f):
            # a field of a nested message (pulls[:].pull_id): walk into the element type
            defs = dict(store.fielddefs[msg_type][1])
            assert field in defs, (path, list(defs))
            kind, detail = defs[field]
            msg_type = detail[0][1] if kind == Nodetype.SEQUENCE and detail[0][0] == Nodetype.NAME else \
                detail if kind == Nodetype.NAME else None


def test_layout_plots_only_what_the_monitor_serves():
    layout = json.loads(LAYOUT.read_text())
    kinds = {k.split('!')[0] for k in layout['configById']}
    assert {'Plot', 'Table', 'DiagnosticSummary', 'Parameters'} <= kinds
    types = {**{t: n for t, (n, _f) in FORWARDED.items()}, **{t: n for t, (n, _c) in DERIVED.items()}}
    paths = paths_in(layout)
    assert any(p.startswith('/monitor/force.') for p in paths) and any('/monitor/pull_trace.' in p for p in paths)
    check_fields(paths, types)


def test_the_bag_layout_reads_only_what_the_recorder_records():
    """layouts/bag.json (./ft view --bag, issue 41 item 9): every topic one the recorder records by default, no
    /monitor/* (a bag has none: with the live layout all seven panels of a bag stayed empty), every field one
    of its type; it plots the forces, the acceleration and the scores, and tables the summaries."""
    from force_tester_common.core.channels import (
        BLOCK_TYPES,
        CORRECTED_TYPE,
        GRAPH_TOPICS,
        PULL_EVENT_TOPIC,
        PULL_EVENT_TYPE,
        PULL_SCORE_TOPIC,
        PULL_SCORE_TYPE,
        SET_SUMMARY_TOPIC,
        SET_SUMMARY_TYPE,
    )
    types = {topic: name for name, (topic, _f) in [*BLOCK_TYPES.items(), CORRECTED_TYPE]}
    types.update({PULL_EVENT_TOPIC: PULL_EVENT_TYPE, PULL_SCORE_TOPIC: PULL_SCORE_TYPE,
                  SET_SUMMARY_TOPIC: SET_SUMMARY_TYPE})
    assert set(types) == set(GRAPH_TOPICS)
    layout = json.loads(LAYOUT.with_name('bag.json').read_text())
    paths = paths_in(layout)
    assert not [p for p in paths if p.startswith('/monitor')]
    check_fields(paths, types)
    plotted = {p.split('.')[0].split('{')[0] for p in paths if not p.startswith(('/pull_event', '/set_summary'))}
    assert plotted == {'/force', '/force_corrected', '/accel', PULL_SCORE_TOPIC}, plotted
    tables = {cfg['topicPath'] for k, cfg in layout['configById'].items() if k.startswith('Table!')}
    assert tables == {PULL_SCORE_TOPIC, SET_SUMMARY_TOPIC, PULL_EVENT_TOPIC}


def test_the_nodes_tab_and_the_difference_plot_read_what_a_late_page_gets_whole():
    """Issue 41: the Nodes tab shows /monitor/nodes (one line a node, STALE when silent); the % plot reads the
    score history (sent again to each client that subscribes), OK pulls only, so a page opened late or after a
    monitor restart plots every OK pull and an INCOMPLETE 287 % does not set the scale."""
    from force_tester_common.core.channels import MONITOR_NODES_TOPIC, SCORE_HISTORY_TOPIC
    layout = json.loads(LAYOUT.read_text())['configById']
    (diag,) = [cfg for k, cfg in layout.items() if k.startswith('DiagnosticSummary!')]
    assert diag['topicToRender'] == MONITOR_NODES_TOPIC
    diffs = layout['Plot!diffs']
    ok_rows = SCORE_HISTORY_TOPIC + '.pulls[:]{status=="OK"}'
    assert diffs['xAxisVal'] == 'currentCustom' and diffs['xAxisPath']['value'] == ok_rows + '.pull'
    assert [p['value'] for p in diffs['paths']] == [f'{ok_rows}.{d}_pct' for d in ('raw', 'corrected', 'filtered')]
