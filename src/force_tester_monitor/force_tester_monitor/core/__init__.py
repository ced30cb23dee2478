"""The monitor's arithmetic, ROS-free (numpy only): sample blocks -> live-trace scalars, pull windows
-> pull traces, arrivals -> topic health."""
