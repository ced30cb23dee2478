"""Where the force_tester_msgs .msg files are (no rosbags: typefacts and typestore both read them)."""

from __future__ import annotations

import functools
import os
from collections.abc import Mapping
from pathlib import Path

from .errors import BagError

MSG_PACKAGE = 'force_tester_msgs'


def msg_files(path: Path) -> list[tuple[str, Path]]:
    """(package, file) pairs for a msg directory or a single .msg file."""
    if not path.exists():
        raise BagError(f'message definition path {str(path)!r} does not exist; '
                       f'expected a <pkg>/msg directory or a .msg file')
    if path.is_file():
        if path.suffix != '.msg':
            raise BagError(f'message definition file {str(path)!r} is not a .msg file')
        return [(path.parent.parent.name, path)]
    files = sorted(path.glob('*.msg'))
    if not files:
        raise BagError(f'message directory {str(path)!r} contains no .msg files')
    return [(path.parent.name, f) for f in files]


def find_msg_dirs(env: Mapping[str, str] = os.environ) -> list[Path]:
    """Directories holding the force_tester_msgs .msg files.

    All '<prefix>/share/force_tester_msgs/msg' for the prefixes in AMENT_PREFIX_PATH
    (in order); if none, the source tree 'src/force_tester_msgs/msg' of the repository
    this file lives in. Raises BagError when nothing is found.
    """
    prefixes = [p for p in env.get('AMENT_PREFIX_PATH', '').split(':') if p]
    found = [Path(p) / 'share' / MSG_PACKAGE / 'msg' for p in prefixes]
    found = [d for d in found if d.is_dir()]
    if found:
        return found
    here = Path(__file__).resolve()
    for ancestor in here.parents:
        candidate = ancestor / 'src' / MSG_PACKAGE / 'msg'
        if candidate.is_dir():
            return [candidate]
    raise BagError(f'{MSG_PACKAGE} message definitions not found: no share/{MSG_PACKAGE}/msg '
                   f'under AMENT_PREFIX_PATH={env.get("AMENT_PREFIX_PATH", "")!r} and no '
                   f'src/{MSG_PACKAGE}/msg above {str(here.parent)!r}')


@functools.lru_cache(maxsize=8)
def msg_dirs_of(ament_prefix_path: str) -> tuple:
    """find_msg_dirs of an AMENT_PREFIX_PATH, found once."""
    return tuple(find_msg_dirs({'AMENT_PREFIX_PATH': ament_prefix_path}))


def type_files(dirs) -> dict:
    """{'pkg/msg/Name': .msg file} of msg directories (or files); earlier entries win (overlay order)."""
    files: dict = {}
    for directory in dirs:
        for package, file in msg_files(Path(directory)):
            files.setdefault(f'{package}/msg/{file.stem}', file)
    return files
