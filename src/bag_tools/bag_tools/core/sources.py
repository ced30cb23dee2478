"""What a source folder holds, told from its file names alone: a DAQ campaign (its campaign.yaml) or a rosbag2 bag
(metadata.yaml, or an .mcap file); and whether a new bag may be written at a path. Kept apart from the DAQ and
conversion modules (and rosbags), so that a command given a bag (`./ft bag correct BAG OUT`) asks this first and
never imports them."""

from __future__ import annotations

from pathlib import Path

from .errors import BagError
from .metadata import METADATA_FILE

#: The file that makes a folder a DAQ campaign.
CAMPAIGN_FILE = 'campaign.yaml'


def source_kind(src: str | Path) -> str:
    """'campaign' (a DAQ export folder) or 'bag' (a rosbag2 directory); BagError otherwise."""
    p = Path(src)
    if (p / CAMPAIGN_FILE).is_file():
        return 'campaign'
    if (p / METADATA_FILE).is_file() or any(p.glob('*.mcap')):
        return 'bag'
    if not p.exists():
        raise BagError(f'source {str(p)!r} does not exist; expected a bag or a campaign folder')
    raise BagError(f'source {str(p)!r} is neither a bag ({METADATA_FILE}) nor a campaign '
                   f'({CAMPAIGN_FILE})')


def check_new_bag_path(path: Path) -> None:
    """A bag is written into a new directory whose parent exists."""
    if path.exists():
        raise BagError(f'bag output path {str(path)!r} exists already; expected a new directory name')
    if not path.parent.is_dir():
        raise BagError(f'parent directory {str(path.parent)!r} of bag output does not exist')
