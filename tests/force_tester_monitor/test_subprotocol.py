"""The monitor's gate (core/subprotocol.py) in front of foxglove-sdk's real server: a client offering only the
protocol's old name is answered 101 with that name, as is one offering the SDK's; a client offering neither gets
the SDK's own 400; without the gate the SDK refuses the old name (what Foxglove Studio 1.48 met)."""
import base64
import os
import socket

import foxglove
import pytest
from force_tester_monitor.core.errors import MonitorError
from force_tester_monitor.core.subprotocol import (
    LEGACY_SUBPROTOCOL,
    SDK_SUBPROTOCOL,
    SubprotocolGate,
    offered,
    translate_request,
)


def handshake(port: int, protocols: str | None, host: str = '127.0.0.1') -> tuple:
    """(status code, the answer's Sec-WebSocket-Protocol or None) of a raw WebSocket upgrade."""
    key = base64.b64encode(os.urandom(16)).decode()
    head = (f'GET / HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n'
            f'Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n'
            + (f'Sec-WebSocket-Protocol: {protocols}\r\n' if protocols else '') + '\r\n')
    with socket.create_connection((host, port), timeout=30) as s:
        s.sendall(head.encode())
        data = b''
        while b'\r\n\r\n' not in data:
            chunk = s.recv(4096)
            if not chunk:
                break
            data += chunk
    lines = data.split(b'\r\n\r\n')[0].decode('latin-1').split('\r\n')
    status = int(lines[0].split()[1])
    proto = [ln.split(':', 1)[1].strip() for ln in lines[1:] if ln.lower().startswith('sec-websocket-protocol:')]
    return status, (proto[0] if proto else None)


@pytest.fixture
def sdk_and_gate():
    server = foxglove.start_server(name='gate test', host='127.0.0.1', port=0)
    gate = SubprotocolGate('127.0.0.1', 0, server.port)
    yield server, gate
    gate.close()
    server.stop()


def test_both_names_are_accepted_through_the_gate(sdk_and_gate):
    server, gate = sdk_and_gate
    assert handshake(server.port, LEGACY_SUBPROTOCOL)[0] == 400      # the SDK alone refuses the old name
    assert handshake(gate.port, LEGACY_SUBPROTOCOL) == (101, LEGACY_SUBPROTOCOL)
    assert handshake(gate.port, SDK_SUBPROTOCOL) == (101, SDK_SUBPROTOCOL)
    assert handshake(gate.port, f'{LEGACY_SUBPROTOCOL}, {SDK_SUBPROTOCOL}') == (101, SDK_SUBPROTOCOL)
    assert handshake(gate.port, 'some.other.v1')[0] == 400
    assert handshake(gate.port, None)[0] == 400


def test_a_gate_on_every_interface_serves_the_lab_network():
    """The monitor's ``host`` 0.0.0.0: a browser on another machine reaches the gate at this machine's address,
    while the SDK's own server stays on loopback."""
    from ft_cli.commands.view import lan_address
    address = lan_address()
    if address.count('.') != 3:
        pytest.skip(f'this machine has no IPv4 address on a default route ({address!r})')
    server = foxglove.start_server(name='gate test', host='127.0.0.1', port=0)
    gate = SubprotocolGate('0.0.0.0', 0, server.port)
    try:
        assert handshake(gate.port, LEGACY_SUBPROTOCOL, host=address) == (101, LEGACY_SUBPROTOCOL)
        with pytest.raises(OSError):
            socket.create_connection((address, server.port), timeout=10).close()
    finally:
        gate.close()
        server.stop()


def test_a_busy_port_is_one_line_naming_it(sdk_and_gate):
    _, gate = sdk_and_gate
    with pytest.raises(MonitorError) as exc:
        SubprotocolGate('127.0.0.1', gate.port, 1)
    assert f'port {gate.port}' in str(exc.value) and 'in use' in str(exc.value)


def test_request_translation():
    req = b'GET / HTTP/1.1\r\nHost: x\r\nsec-websocket-protocol: foxglove.websocket.v1\r\nX: y'
    assert offered(req) == [LEGACY_SUBPROTOCOL]
    head, answer = translate_request(req)
    assert offered(head) == [SDK_SUBPROTOCOL] and answer == LEGACY_SUBPROTOCOL and head.endswith(b'X: y')
    both = b'GET / HTTP/1.1\r\nSec-WebSocket-Protocol: a, foxglove.sdk.v1\r\n'
    assert translate_request(both) == (both, None)
