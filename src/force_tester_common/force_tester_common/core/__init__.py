"""Facts shared by every package (pure Python + numpy; no ROS): the sample clock, units, channel
and topic tables, pull-event codes, correction defaults and ranges, score field names."""
