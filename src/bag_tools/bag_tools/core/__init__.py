"""ROS-free core of bag_tools: rosbag2 (MCAP) writing, reading, inspection, scheduling.

Imports only rosbags, numpy, yaml and the standard library (no rclpy). The names below are
imported from their modules on first use.
"""
from force_tester_common.core.lazy import lazy_exports

_EXPORTS = {
    'BagError': 'errors', 'bag_info': 'info', 'format_info': 'info', 'METADATA_VERSION': 'metadata',
    'Schedule': 'playback', 'schedule': 'playback', 'BagMessage': 'reader', 'BagReaderHandle': 'reader',
    'TopicSummary': 'reader', 'open_bag': 'reader', 'default_typestore': 'typestore',
    'find_msg_dirs': 'msgdirs', 'make_typestore': 'typestore', 'BagWriter': 'writer',
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
