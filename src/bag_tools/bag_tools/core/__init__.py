"""ROS-free core of bag_tools: rosbag2 (MCAP) writing, reading, inspection, scheduling.

Imports only rosbags, numpy, yaml and the standard library (no rclpy).
"""

from .errors import BagError
from .info import bag_info, format_info
from .metadata import METADATA_VERSION
from .playback import Schedule, schedule
from .reader import BagMessage, BagReaderHandle, TopicSummary, open_bag
from .typestore import default_typestore, find_msg_dirs, make_typestore
from .writer import BagWriter

__all__ = [
    'METADATA_VERSION', 'BagError', 'BagMessage', 'BagReaderHandle', 'BagWriter', 'Schedule',
    'TopicSummary', 'bag_info', 'default_typestore', 'find_msg_dirs', 'format_info',
    'make_typestore', 'open_bag', 'schedule',
]
