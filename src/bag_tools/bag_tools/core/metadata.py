"""rosbag2's metadata.yaml, read and written one way: PyYAML's C loader and dumper, block style as
rosbags writes it. (ruamel, which rosbags uses, costs about 10 ms a bag here: a third of `correct`.)

Our writers that do not go through rosbags (the split writer, ExtendedBag) write it here,
last and atomically (a temporary file renamed), so a bag without metadata.yaml is unfinished.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import yaml

from .errors import BagError, one_line

#: rosbag2 metadata version written. Jazzy writes and reads version 9.
METADATA_VERSION = 9
METADATA_FILE = 'metadata.yaml'
#: The ROS distribution our bags are written for (metadata.yaml's ros_distro).
ROS_DISTRO = 'jazzy'
ROOT_KEY = 'rosbag2_bagfile_information'


_LOADER = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)
_DUMPER = getattr(yaml, 'CSafeDumper', yaml.SafeDumper)


def dump_info(info: dict[str, Any]) -> str:
    """The bag information mapping as YAML (what rosbag2 also embeds in each MCAP file)."""
    return yaml.dump(info, Dumper=_DUMPER, default_flow_style=False, sort_keys=False)


def write_metadata(bag_dir: str | Path, info: dict[str, Any]) -> None:
    """Write bag_dir/metadata.yaml for the bag information mapping info (atomically)."""
    bag_dir = Path(bag_dir)
    tmp = bag_dir / f'{METADATA_FILE}.tmp'
    tmp.write_text(dump_info({ROOT_KEY: info}), encoding='utf-8')
    os.replace(tmp, bag_dir / METADATA_FILE)


def load_metadata(bag_dir: str | Path) -> dict[str, Any]:
    """The bag information mapping of a rosbag2 directory; BagError (one line) for a missing
    path, a file, a missing or invalid metadata.yaml or a missing storage file."""
    path = Path(bag_dir)
    if not path.exists():
        raise BagError(f'bag {str(path)!r} does not exist; expected a rosbag2 directory')
    if not path.is_dir():
        raise BagError(f'bag {str(path)!r} is a file; expected a rosbag2 directory '
                       f'containing {METADATA_FILE} and .mcap files')
    meta = path / METADATA_FILE
    if not meta.is_file():
        if any(path.glob('*.mcap')) or any(path.parent.glob(f'.{path.name}.*.splits')):
            # what a killed recorder leaves (a split recorder's first file is in .splits)
            raise BagError(f'bag {str(path)!r} needs a reindex: run ./ft bag reindex on it '
                           '(an interrupted recording left .mcap data but no '
                           f'{METADATA_FILE})')
        raise BagError(f'bag {str(path)!r} has no {METADATA_FILE}; expected a rosbag2 '
                       'directory')
    try:
        doc = yaml.load(meta.read_text(encoding='utf-8'), Loader=_LOADER)
    except Exception as exc:  # noqa: BLE001 - any parse failure is the same bad input
        raise BagError(f'metadata {str(meta)!r} is not valid YAML: {one_line(exc)}') from None
    info = doc.get(ROOT_KEY) if isinstance(doc, dict) else None
    if not isinstance(info, dict):
        raise BagError(f'metadata {str(meta)!r} lacks {ROOT_KEY}; expected a rosbag2 {METADATA_FILE}')
    rels = info.get('relative_file_paths') or []
    if not isinstance(rels, list):     # found by fuzzing: an int here was a TypeError
        raise BagError(f'metadata {str(meta)!r}: relative_file_paths {rels!r} is invalid; expected a list of the '
                       'storage file names')
    for rel in rels:
        if not (path / str(rel)).is_file():
            raise BagError(f'bag {str(path)!r} lists storage file {str(rel)!r} in '
                           f'{METADATA_FILE} but it is missing')
    return info
