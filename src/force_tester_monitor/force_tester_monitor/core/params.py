"""The monitor's parameter defaults and ranges (inclusive), defined once: the node's ParamSpecs,
the core's MonitorParams and the tests take them from here."""
from __future__ import annotations

import ipaddress
from dataclasses import dataclass

from force_tester_common.core.channels import ACCEL_TYPE, BLOCK_TYPES, ENCODER_TYPE, MOTOR_TYPE

from .errors import MonitorError

HOST = '127.0.0.1'                 # the WebSocket listens on loopback only by default; 0.0.0.0 (or an
                                   # interface's address) serves browsers on the lab network
PORT = 8765                        # Foxglove's default WebSocket port
PORT_RANGE = (0, 65535)            # 0: any free port (the node logs the one it got)
FORCE_EVERY = 2                    # /force_corrected blocks per /monitor/force message: 50 Hz at the
                                   # default 10 ms blocks (each message carries the maxima, so no peak is lost)
FORCE_EVERY_RANGE = (1, 10_000)
PERIOD_S = 0.05                    # the monitor works through what arrived this often
PERIOD_RANGE_S = (0.001, 1.0)
HEALTH_PERIOD_S = 1.0              # /monitor/health period
HEALTH_PERIOD_RANGE_S = (0.1, 60.0)
HEALTH_WINDOW_S = 5.0              # span of the rates and latency percentiles
HEALTH_WINDOW_RANGE_S = (0.5, 600.0)
TRACE_MARGIN_S = 0.02              # pull trace: time kept before and after the loaded window
TRACE_MARGIN_RANGE_S = (0.0, 10.0)
MAX_TRACE_S = 60.0                 # pull trace: a pull longer than this keeps its first MAX_TRACE_S
MAX_TRACE_RANGE_S = (0.1, 3600.0)
TRACE_TIMEOUT_S = 3.0              # an ended pull's trace goes out when no block came for this long (stopped short)
TRACE_TIMEOUT_RANGE_S = (0.1, 600.0)
HISTORY_ROWS = 500                 # /monitor/score_history: the newest pulls it lists (a set's statistics cover all)
HISTORY_ROWS_RANGE = (1, 100_000)
BACKLOG = 1024                     # messages the server queues per client; the oldest goes first when full
BACKLOG_RANGE = (16, 1_000_000)
DEPTH = 10_000                     # subscription queue (best effort, keep last; 10 s of 1 ms blocks, as the graph's):
                                   # a monitor that falls further behind loses blocks, and never delays a publisher
DEPTH_RANGE = (1, 100_000)
# The block topics no monitor topic is made from. With ``on_demand`` (the default) the monitor
# subscribes to them only while a Foxglove client watches them, and their health is in
# /monitor/health only then. /force and /force_corrected are always watched: they feed the live
# trace, the pull traces and the scoreboard's health line.
ON_DEMAND_TOPICS = (BLOCK_TYPES[MOTOR_TYPE][0], BLOCK_TYPES[ENCODER_TYPE][0], BLOCK_TYPES[ACCEL_TYPE][0])
ON_DEMAND = True


def _check(name: str, value, rng: tuple, kind: type):
    if isinstance(value, bool) or not isinstance(value, (int, float) if kind is float else int):
        raise MonitorError(f'{name} {value!r} is invalid; expected a {kind.__name__} in [{rng[0]}, {rng[1]}]')
    if not rng[0] <= value <= rng[1]:
        raise MonitorError(f'{name} {value!r} is out of range; expected a value in [{rng[0]}, {rng[1]}]')
    return kind(value)


@dataclass(frozen=True)
class MonitorParams:
    host: str = HOST
    port: int = PORT
    force_every: int = FORCE_EVERY
    period_s: float = PERIOD_S
    health_period_s: float = HEALTH_PERIOD_S
    health_window_s: float = HEALTH_WINDOW_S
    trace_margin_s: float = TRACE_MARGIN_S
    max_trace_s: float = MAX_TRACE_S
    trace_timeout_s: float = TRACE_TIMEOUT_S
    history_rows: int = HISTORY_ROWS
    backlog: int = BACKLOG
    depth: int = DEPTH
    on_demand: bool = ON_DEMAND

    def __post_init__(self):
        for name, rng, kind in (('port', PORT_RANGE, int), ('force_every', FORCE_EVERY_RANGE, int),
                                ('period_s', PERIOD_RANGE_S, float),
                                ('health_period_s', HEALTH_PERIOD_RANGE_S, float),
                                ('health_window_s', HEALTH_WINDOW_RANGE_S, float),
                                ('trace_margin_s', TRACE_MARGIN_RANGE_S, float),
                                ('max_trace_s', MAX_TRACE_RANGE_S, float),
                                ('trace_timeout_s', TRACE_TIMEOUT_RANGE_S, float),
                                ('history_rows', HISTORY_ROWS_RANGE, int),
                                ('backlog', BACKLOG_RANGE, int), ('depth', DEPTH_RANGE, int)):
            object.__setattr__(self, name, _check(name, getattr(self, name), rng, kind))
        try:
            ipaddress.ip_address(self.host)
        except ValueError:
            raise MonitorError(f'host {self.host!r} is invalid; expected an IP address such as {HOST} or 0.0.0.0') \
                from None
        if not isinstance(self.on_demand, bool):
            raise MonitorError(f'on_demand {self.on_demand!r} is invalid; expected true or false')
