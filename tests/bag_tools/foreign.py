"""Bags that look like other people's: written here, with the mcap library and rosbags, the way
`ros2 bag record` on a full ROS install (or an older distro) writes them.

Each bag holds a small force-tester campaign (our block topics and pull events, as
campaign_to_bag writes them) plus topics we cannot know: a vendor message type with no Python
package, a service-event topic whose schema is the srv text (as rosbag2 writes `*_Event`
schemas) and std_msgs/msg/String chatter (a type rclpy has). A `Spec` picks the storage
(MCAP or sqlite3), chunk or file compression, split files, old `pkg/Type` names, QoS strings
that differ between metadata.yaml and the storage file, and empty bags.
"""
from __future__ import annotations

import shutil
import sqlite3
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml
from daq_data import T0, make_pulls
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as RosbagsWriter
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from bag_tools.core.convert import campaign_to_bag
from bag_tools.core.daq import write_campaign
from bag_tools.core.reader import open_bag
from bag_tools.core.typefacts import type_facts

try:
    from compression import zstd  # Python >= 3.14
except ImportError:
    from backports import zstd

VENDOR_TYPE = 'vendor_msgs/msg/Status'
VENDOR_DEF = 'uint8 level\nstring text\n'
VENDOR_TOPIC = '/vendor/status'
SERVICE = 'vendor_srvs/srv/SetGain'
SERVICE_EVENT_TYPE = f'{SERVICE}_Event'
SERVICE_DEF = 'float64 gain\n---\nbool ok\nstring message\n'  # the srv text, as rosbag2 embeds it
SERVICE_TOPIC = '/set_gain/_service_event'
CHATTER_TYPE = 'std_msgs/msg/String'
CHATTER_TOPIC = '/chatter'
FOREIGN_COUNTS = {VENDOR_TOPIC: 4, SERVICE_TOPIC: 2, CHATTER_TOPIC: 5}
#: Topics whose type has no Python package here: `play` must skip them.
UNPLAYABLE = (VENDOR_TOPIC, SERVICE_TOPIC)

_QOS = ('- history: 3\n  depth: 0\n  reliability: {rel}\n  durability: {dur}\n  deadline:\n'
        '    sec: 9223372036\n    nsec: 854775807\n  lifespan:\n    sec: 9223372036\n'
        '    nsec: 854775807\n  liveliness: 1\n  liveliness_lease_duration:\n'
        '    sec: 9223372036\n    nsec: 854775807\n  avoid_ros_namespace_conventions: false')
QOS_METADATA = _QOS.format(rel=1, dur=2)  # reliable, volatile
QOS_STORAGE = _QOS.format(rel=1, dur=1)   # reliable, transient local: what the recorder saw
NO_START = 2**63 - 1


@dataclass(frozen=True)
class Spec:
    """How a foreign bag is written.

    storage 'mcap' or 'sqlite3'; chunk: MCAP chunk compression ('', 'zstd', 'lz4'); file:
    rosbag2 file compression of each storage file ('', 'zstd', or 'lz4', which rosbag2 has no
    plugin for); message: rosbag2 per-message zstd compression; split: storage files;
    old_names: every type written as 'pkg/Type'; qos_differs: metadata.yaml's QoS strings
    differ from the storage file's; empty: topics but no messages; counts_off: metadata.yaml
    claims that many more /chatter messages than the storage holds; version: metadata version.
    """

    name: str
    storage: str = 'mcap'
    chunk: str = ''
    file: str = ''
    message: bool = False
    split: int = 1
    old_names: bool = False
    qos_differs: bool = False
    empty: bool = False
    counts_off: int = 0
    version: int = 9
    distro: str = 'jazzy'

    @property
    def refused(self) -> bool:
        """rosbag2 itself cannot read it (no lz4 file compressor)."""
        return self.file == 'lz4'


SPECS = (
    Spec('jazzy_mcap_services'),
    Spec('qos_differs', qos_differs=True),
    Spec('old_names', old_names=True, version=4, distro='foxy', storage='sqlite3'),
    Spec('old_names_mcap', old_names=True, version=5, distro='galactic'),
    Spec('sqlite3', storage='sqlite3', distro='humble', version=5),
    Spec('sqlite3_qos_differs', storage='sqlite3', qos_differs=True, distro='humble'),
    Spec('chunk_zstd', chunk='zstd'),
    Spec('chunk_lz4', chunk='lz4'),
    Spec('file_zstd', file='zstd'),
    Spec('file_zstd_sqlite3', file='zstd', storage='sqlite3'),
    Spec('message_zstd_sqlite3', message=True, storage='sqlite3'),
    Spec('split3', split=3, chunk='lz4'),
    Spec('split2_sqlite3_qos', split=2, storage='sqlite3', qos_differs=True),
    Spec('counts_differ', counts_off=3),
    Spec('empty', empty=True),
    Spec('empty_sqlite3', empty=True, storage='sqlite3', version=4),
    Spec('file_lz4', file='lz4'),
)


def old_name(type_name: str) -> str:
    pkg, _kind, name = type_name.split('/')
    return f'{pkg}/{name}'


def _vendor_store():
    """Jazzy + the vendor types. rosbags names every parsed type pkg/msg/Name, so the service's
    request and response are built under msg names and the event renamed to its srv name."""
    store = get_typestore(Stores.ROS2_JAZZY)
    types = get_types_from_msg(VENDOR_DEF, VENDOR_TYPE)
    request, response = SERVICE_DEF.split('---\n')
    pkg, _srv, name = SERVICE.split('/')
    types.update(get_types_from_msg(request, f'{pkg}/msg/{name}_Request'))
    types.update(get_types_from_msg(response, f'{pkg}/msg/{name}_Response'))
    event = get_types_from_msg(
        f'service_msgs/msg/ServiceEventInfo info\n{pkg}/msg/{name}_Request[<=1] request\n'
        f'{pkg}/msg/{name}_Response[<=1] response\n', f'{pkg}/msg/{name}_Event')
    types[SERVICE_EVENT_TYPE] = event[f'{pkg}/msg/{name}_Event']
    store.register(types)
    return store


def foreign_messages(t0: int) -> list:
    """(topic, type, stamp, cdr) of the topics we do not own, from t0 on."""
    store = _vendor_store()
    T = store.types
    out = []
    for i in range(FOREIGN_COUNTS[VENDOR_TOPIC]):
        msg = T[VENDOR_TYPE](level=i, text=f'status {i}')
        out.append((VENDOR_TOPIC, VENDOR_TYPE, t0 + 3_000_000 * i + 11,
                    store.serialize_cdr(msg, VENDOR_TYPE)))
    for i in range(FOREIGN_COUNTS[SERVICE_TOPIC]):
        info = T['service_msgs/msg/ServiceEventInfo'](
            event_type=i, stamp=T['builtin_interfaces/msg/Time'](sec=t0 // 10**9, nanosec=i),
            client_gid=np.zeros(16, np.uint8), sequence_number=1)
        pkg, _srv, name = SERVICE.split('/')
        req = [T[f'{pkg}/msg/{name}_Request'](gain=1.5)] if i == 0 else []
        res = [T[f'{pkg}/msg/{name}_Response'](ok=True, message='done')] if i else []
        msg = T[SERVICE_EVENT_TYPE](info=info, request=req, response=res)
        out.append((SERVICE_TOPIC, SERVICE_EVENT_TYPE, t0 + 5_000_000 * i + 13,
                    store.serialize_cdr(msg, SERVICE_EVENT_TYPE)))
    for i in range(FOREIGN_COUNTS[CHATTER_TOPIC]):
        msg = T[CHATTER_TYPE](data=f'hello {i}')
        out.append((CHATTER_TOPIC, CHATTER_TYPE, t0 + 2_000_000 * i + 17,
                    store.serialize_cdr(msg, CHATTER_TYPE)))
    return out


def definitions() -> dict:
    """type -> (definition text as rosbag2 embeds it, RIHS01 hash)."""
    fake = 'RIHS01_' + '5a' * 32  # a hash we cannot check, as for any type we do not have
    store = get_typestore(Stores.ROS2_JAZZY)
    out = {VENDOR_TYPE: (VENDOR_DEF, fake), SERVICE_EVENT_TYPE: (SERVICE_DEF, fake),
           CHATTER_TYPE: (store.generate_msgdef(CHATTER_TYPE, ros_version=2)[0],
                          store.hash_rihs01(CHATTER_TYPE))}
    return out


def campaign_messages(work: Path) -> list:
    """(topic, type, stamp, cdr) of a 3-pull campaign, as our own tools write it."""
    camp = write_campaign(work / 'camp', make_pulls(3, start=T0))
    bag = campaign_to_bag(camp, work / 'own_bag')
    with open_bag(bag) as b:
        msgs = [(m.topic, m.type_name, m.stamp_ns, m.cdr) for m in b.messages()]
    shutil.rmtree(work / 'own_bag')
    return msgs


def _topics(msgs: list, extra_types: dict) -> dict:
    """topic -> type in first-seen order, with the types of `extra_types` (topics with none)."""
    out: dict = {}
    for topic, type_name, *_ in msgs:
        out.setdefault(topic, type_name)
    out.update(extra_types)
    return out


def _mcap_file(path: Path, topics: dict, defs: dict, msgs: list, qos: str, spec: Spec,
               names) -> None:
    chunk = {'': CompressionType.NONE, 'lz4': CompressionType.LZ4,
             'zstd': CompressionType.ZSTD}[spec.chunk]
    with path.open('wb') as f:
        w = McapWriter(f, chunk_size=64 * 1024, compression=chunk)
        w.start(profile='ros2', library='vendor-recorder 1.0')
        schemas, channels = {}, {}
        for topic, type_name in topics.items():
            text, rihs = defs[type_name]
            if type_name not in schemas:
                schemas[type_name] = w.register_schema(names(type_name), 'ros2msg',
                                                       text.encode())
            channels[topic] = w.register_channel(
                topic, 'cdr', schemas[type_name],
                {'offered_qos_profiles': qos, 'topic_type_hash': rihs})
        for seq, (topic, _type, stamp, cdr) in enumerate(msgs):
            w.add_message(channels[topic], stamp, cdr, stamp, seq)
        w.finish()


def _sqlite_file(path: Path, topics: dict, defs: dict, msgs: list, qos: str, spec: Spec,
                 names) -> None:
    """One .db3 written by rosbags, its QoS column then set as the recorder saw it."""
    tmp = path.parent / f'.{path.stem}_tmp'
    w = RosbagsWriter(tmp, version=9, storage_plugin=StoragePlugin.SQLITE3)
    w.open()
    conns = {}
    for topic, type_name in topics.items():
        text, rihs = defs[type_name]
        conns[topic] = w.add_connection(topic, names(type_name), msgdef=text, rihs01=rihs)
    for topic, _type, stamp, cdr in msgs:
        w.write(conns[topic], stamp, zstd.compress(cdr) if spec.message else cdr)
    w.close()
    db = next(tmp.glob('*.db3'))
    con = sqlite3.connect(db)
    with con:
        con.execute('UPDATE topics SET offered_qos_profiles = ?', (qos,))
    con.close()
    db.rename(path)
    shutil.rmtree(tmp)


def write_foreign_bag(spec: Spec, parent: Path, base: list, defs_override=None) -> Path:
    """Write the bag of `spec` as parent/spec.name from our campaign's messages `base`
    (campaign_messages) plus the foreign topics. defs_override: {type: definition text} to
    embed instead of the real one. Returns the bag directory."""
    bag = parent / spec.name
    bag.mkdir(parents=True)
    defs = {t: type_facts(t)[:2] for _tp, t, *_ in base}
    defs.update(definitions())
    for type_name, text in (defs_override or {}).items():
        defs[type_name] = (text, defs[type_name][1])
    t0 = min(m[2] for m in base)
    msgs = sorted([*base, *foreign_messages(t0)], key=lambda m: m[2])
    topics = _topics(msgs, {})
    if spec.empty:
        msgs = []

    def names(type_name):
        return old_name(type_name) if spec.old_names else type_name

    storage_qos = QOS_STORAGE if spec.qos_differs else QOS_METADATA
    ext = '.mcap' if spec.storage == 'mcap' else '.db3'
    parts = [msgs]
    if spec.split > 1:  # split by time: contiguous runs of messages
        size = -(-len(msgs) // spec.split)
        parts = [msgs[i * size:(i + 1) * size] for i in range(spec.split)]
    files = []
    for i, part in enumerate(parts):
        path = bag / f'{spec.name}_{i}{ext}'
        write = _mcap_file if spec.storage == 'mcap' else _sqlite_file
        write(path, topics, defs, part, storage_qos, spec, names)
        if spec.file:
            packed = path.with_name(path.name + '.' + spec.file)
            if spec.file == 'zstd':
                packed.write_bytes(zstd.compress(path.read_bytes()))
            else:
                import lz4.frame
                packed.write_bytes(lz4.frame.compress(path.read_bytes()))
            path.unlink()
            path = packed
        start = min((m[2] for m in part), default=NO_START)
        end = max((m[2] for m in part), default=NO_START)
        files.append({'path': path.name, 'starting_time': {'nanoseconds_since_epoch': start},
                      'duration': {'nanoseconds': end - start}, 'message_count': len(part)})
    counts = {t: sum(1 for m in msgs if m[0] == t) for t in topics}
    counts[CHATTER_TOPIC] += spec.counts_off
    start = min((m[2] for m in msgs), default=NO_START)
    end = max((m[2] for m in msgs), default=NO_START)
    info = {
        'version': spec.version,
        'storage_identifier': spec.storage,
        'duration': {'nanoseconds': end - start},
        'starting_time': {'nanoseconds_since_epoch': start},
        'message_count': len(msgs) + spec.counts_off,
        'topics_with_message_count': [
            {'topic_metadata': {'name': t, 'type': names(ty), 'serialization_format': 'cdr',
                                'offered_qos_profiles': QOS_METADATA,
                                **({'type_description_hash': defs[ty][1]}
                                   if spec.version >= 8 else {})},
             'message_count': counts[t]} for t, ty in topics.items()],
        'compression_format': spec.file or ('zstd' if spec.message else ''),
        'compression_mode': 'file' if spec.file else ('message' if spec.message else ''),
        'relative_file_paths': [f['path'] for f in files],
    }
    if spec.version >= 5:
        info['files'] = files
    if spec.version >= 6:
        info['custom_data'] = None
        info['ros_distro'] = spec.distro
    (bag / 'metadata.yaml').write_text(
        yaml.safe_dump({'rosbag2_bagfile_information': info}, sort_keys=False))
    return bag


def message_counts(base: list) -> dict:
    """topic -> messages every foreign bag holds (when not empty)."""
    out = dict(FOREIGN_COUNTS)
    for topic, *_ in base:
        out[topic] = out.get(topic, 0) + 1
    return out
