"""Where a node's relative file parameters resolve: under ROS_HOME, as ROS resolves its own
files ($ROS_HOME/log, ...), so that a node finds the same file whatever directory it was started
from (pure Python: no ROS import)."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Mapping, Optional

ROS_HOME_ENV = 'ROS_HOME'
DEFAULT_ROS_HOME = '~/.ros'   # ROS 2's default when ROS_HOME is not set


def ros_home(env: Optional[Mapping[str, str]] = None) -> Path:
    """$ROS_HOME, else ~/.ros (with ~ expanded)."""
    env = os.environ if env is None else env
    return Path(env.get(ROS_HOME_ENV) or DEFAULT_ROS_HOME).expanduser()


def under_ros_home(path: str | Path, env: Optional[Mapping[str, str]] = None) -> Path:
    """``path`` as a node uses it: absolute (or ~/...) as given, a relative one under ros_home()."""
    p = Path(path).expanduser()
    return p if p.is_absolute() else ros_home(env) / p
