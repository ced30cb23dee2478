"""What one host sends over a link, read from the RTPS messages in its outgoing frames (ROS-free).

    python rtps_sniff.py DEV      (inside the host's namespace; root)

A packet socket on DEV sees every frame the device transmits, including those the receiving end
then loses. Each user-data DATA or DATA_FRAG submessage is keyed by (destination address and
port, writer GUID, sequence number, fragment): a key seen before is a retransmission. Prints
'ready', then on SIGTERM or SIGINT one JSON line: frames and bytes sent, user-data submessages
and bytes sent the first time and again, discovery (built-in endpoint) traffic, reliability
control (HEARTBEAT, ACKNACK, GAP, NACK_FRAG, HEARTBEAT_FRAG), and the frames the socket itself
missed (its buffer overflowed: then the figures are short by that many).
"""
from __future__ import annotations

import json
import signal
import socket
import struct
import sys

ETH_P_ALL, PACKET_OUTGOING = 0x0003, 4
SOL_PACKET, PACKET_STATISTICS, SO_RCVBUFFORCE = 263, 6, 33
DATA, DATA_FRAG = 0x15, 0x16
CONTROL = {0x06: 'ACKNACK', 0x07: 'HEARTBEAT', 0x08: 'GAP', 0x12: 'NACK_FRAG', 0x13: 'HEARTBEAT_FRAG'}
PAD, INFO_TS = 0x01, 0x09


class Tally:
    def __init__(self):
        self.seen = set()
        self.out = {'frames': 0, 'frame_bytes': 0, 'rtps_frames': 0, 'data_first': 0, 'data_first_bytes': 0,
                    'data_again': 0, 'data_again_bytes': 0, 'discovery': 0, 'discovery_bytes': 0,
                    'control': 0, 'control_bytes': 0}

    def frame(self, f: bytes) -> None:
        """Count one outgoing Ethernet frame."""
        out = self.out
        out['frames'] += 1
        out['frame_bytes'] += len(f)
        if len(f) < 42 or f[12:14] != b'\x08\x00' or f[23] != 17:   # IPv4 and UDP only
            return
        ip = 14 + (f[14] & 0x0F) * 4
        dst = f[30:34] + f[ip + 2:ip + 4]
        m = f[ip + 8:]
        if len(m) < 20 or m[:4] != b'RTPS':
            return
        out['rtps_frames'] += 1
        prefix, o = m[8:20], 20
        while o + 4 <= len(m):
            kind, flags = m[o], m[o + 1]
            end = '<' if flags & 1 else '>'
            (length,) = struct.unpack_from(end + 'H', m, o + 2)
            size = 4 + (length if length or kind in (PAD, INFO_TS) else len(m) - o - 4)
            body = o + 4
            if kind in (DATA, DATA_FRAG) and body + 20 <= len(m):
                writer = m[body + 8:body + 12]
                if writer[3] & 0xC0:   # a built-in (discovery) writer: announcements repeat on purpose
                    out['discovery'] += 1
                    out['discovery_bytes'] += size
                else:
                    high, low = struct.unpack_from(end + 'iI', m, body + 12)
                    frag = struct.unpack_from(end + 'I', m, body + 20)[0] if kind == DATA_FRAG else 0
                    key = (dst, prefix, writer, (high << 32) | low, frag)
                    again = key in self.seen
                    self.seen.add(key)
                    name = 'data_again' if again else 'data_first'
                    out[name] += 1
                    out[name + '_bytes'] += size
            elif kind in CONTROL:
                out['control'] += 1
                out['control_bytes'] += size
            o += size


def sniff(dev: str) -> dict:
    stop = []
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.append(True))
    s = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETH_P_ALL))
    s.setsockopt(socket.SOL_SOCKET, SO_RCVBUFFORCE, 32 * 1024 * 1024)
    s.bind((dev, ETH_P_ALL))
    s.settimeout(0.2)
    s.getsockopt(SOL_PACKET, PACKET_STATISTICS, 8)   # reading resets the socket's counters
    tally = Tally()
    print('ready', flush=True)
    while not stop:
        try:
            frame, addr = s.recvfrom(65536)
        except (TimeoutError, InterruptedError):
            continue
        if addr[2] == PACKET_OUTGOING:
            tally.frame(frame)
    s.setblocking(False)
    while True:   # what is still in the buffer
        try:
            frame, addr = s.recvfrom(65536)
        except BlockingIOError:
            break
        if addr[2] == PACKET_OUTGOING:
            tally.frame(frame)
    _packets, drops = struct.unpack('II', s.getsockopt(SOL_PACKET, PACKET_STATISTICS, 8))
    return {**tally.out, 'missed_by_sniffer': drops}


if __name__ == '__main__':
    if len(sys.argv) != 2:
        sys.exit('usage: rtps_sniff.py DEV')
    print(json.dumps(sniff(sys.argv[1])), flush=True)
