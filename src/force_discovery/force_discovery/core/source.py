"""Where a campaign's pulls come from, one at a time (memory flat in the number of pulls): a campaign folder in the
DAQ export format, read pull by pull, or (meta, channels) pairs already in memory. ROS-free.

A ``PullRef`` names one pull and says how to get its channels; it is small (except for in-memory pulls, which
carry their arrays) and picklable, so a Dask worker can load the pull itself.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence, Tuple

from bag_tools.core.daq import PullJob, campaign_channels, campaign_index, files_index, read_pull
from force_tester_common.core.channels import REQUIRED_CHANNELS

from .errors import DiscoveryError


@dataclass(frozen=True)
class PullRef:
    """One pull of a campaign: a file of a campaign folder (folder, meta, rate_hz), or channels in memory."""

    name: str
    folder: Optional[str] = None
    meta: Optional[dict] = None          # the pull's campaign.yaml entry, validated (bag_tools.core.daq.check_meta)
    entry: Optional[dict] = None         # ... as written (a TDMS file's channel map is in it)
    rate_hz: Optional[float] = None      # campaign.yaml's sample_rate_hz (None: from the time column)
    channels: Optional[dict] = None      # in-memory pulls: column -> array
    channel_map: Optional[object] = None  # the campaign's channel map (bag_tools ChannelMap: lab files in volts)
    absent: tuple = ()                   # required channels the campaign does not have (campaign.yaml absent:)

    def __repr__(self) -> str:
        return f'PullRef({self.name!r})'


def campaign_refs(folder) -> list:
    """PullRef per pull of a campaign folder (campaign.yaml read and checked as read_campaign checks it; no pull
    data read). BagError for a missing or malformed campaign.yaml or a missing pull file."""
    path, rate, _rig, entries = campaign_index(folder)
    cmap, absent = campaign_channels(path)
    return [PullRef(meta['file'], str(Path(path).resolve()), meta, dict(entry), rate, None, cmap, tuple(absent))
            for meta, entry in entries]


def file_refs(files, channel_map=None) -> list:
    """PullRef per DAQ file given one by one, with a channel map and no campaign.yaml (bag_tools.core.daq.files_index;
    no pull data read)."""
    cmap, absent, entries = files_index(files, channel_map)
    return [PullRef(meta['file'], folder, meta, {}, None, None, cmap, tuple(absent)) for folder, meta in entries]


def memory_refs(campaign_pulls: Sequence) -> list:
    """PullRef per (meta, channels) pair; the pull's name is meta['file']."""
    return [PullRef(str(meta.get('file', '?')), meta=meta, channels=ch) for meta, ch in campaign_pulls]


def load_channels(ref: PullRef) -> Tuple[dict, dict]:
    """(meta, channels) of one pull: read from its file (and checked as read_campaign checks it), or as given."""
    if ref.channels is not None:
        return ref.meta, ref.channels
    read = read_pull(PullJob(Path(ref.folder) / ref.meta['file'], (ref.entry or {}).get('map'), ref.rate_hz,
                             ref.channel_map, ref.absent))
    return ref.meta, read.channels


def rated_ranges(ref: PullRef) -> dict:
    """{channel: the sensor's rated range (+/-, SI)} where the campaign's channel map gives one (range:)."""
    specs = getattr(ref.channel_map, 'specs', None) or {}
    return {c: sp.rated for c, sp in specs.items() if getattr(sp, 'rated', None)}


def campaign_absent(refs: Sequence[PullRef]) -> tuple:
    """The required channels a campaign does not have: campaign.yaml's absent: (with its channel map's) for pulls
    of a folder; for pulls in memory, the required channels the first pull lacks."""
    if not refs:
        return ()
    r = refs[0]
    if r.channels is None:
        return tuple(r.absent)
    absent = tuple(c for c in REQUIRED_CHANNELS if c not in r.channels)
    for o in refs[1:]:
        diff = [c for c in REQUIRED_CHANNELS if (c in absent) != (o.channels is not None and c not in o.channels)]
        if diff:
            have, lack = (o, r) if diff[0] in absent else (r, o)
            raise DiscoveryError(f'pull {lack.name!r} has no {diff[0]!r} channel but pull {have.name!r} has; expected '
                                 'the same channels in every pull (a channel the rig lacks is absent from all)')
    return absent


__all__ = ['PullRef', 'campaign_absent', 'campaign_refs', 'file_refs', 'memory_refs', 'load_channels', 'rated_ranges']
