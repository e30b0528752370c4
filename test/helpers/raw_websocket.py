"""A Foxglove WebSocket client written on a bare socket, for the hostile-peer tests: it can
subscribe to every channel and then never read (a laptop asleep with the tab open), which no
well-behaved client library lets a test do. `stalled` tells from the kernel's own socket
tables (/proc/net/tcp) when the server has data queued that the client does not take."""
import base64
import json
import os
import socket
import struct
from pathlib import Path

SUBPROTOCOL = "foxglove.sdk.v1"


class RawClient:
    def __init__(self, port: int, host: str = "127.0.0.1", receive_buffer: int = 4096,
                 protocol: str = SUBPROTOCOL):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        # Before connect: the window the client offers stays small.
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, receive_buffer)
        self.sock.connect((host, port))
        self.server_port = port
        self.port = self.sock.getsockname()[1]
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall((f"GET / HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\n"
                           f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
                           f"Sec-WebSocket-Version: 13\r\nSec-WebSocket-Protocol: {protocol}"
                           f"\r\n\r\n").encode())
        self._buffer = b""
        while b"\r\n\r\n" not in self._buffer:
            chunk = self.sock.recv(4096)
            if not chunk:
                break
            self._buffer += chunk
        head, _, self._buffer = self._buffer.partition(b"\r\n\r\n")
        self.status = head.split(b"\r\n", 1)[0].decode()

    def send_text(self, text: str) -> None:
        data, mask = text.encode(), os.urandom(4)
        n = len(data)
        header = bytes([0x81]) + (bytes([0x80 | n]) if n < 126 else
                                  bytes([0x80 | 126]) + struct.pack(">H", n) if n < 65536 else
                                  bytes([0x80 | 127]) + struct.pack(">Q", n))
        self.sock.sendall(header + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(data)))

    def _frame(self) -> tuple[int, bytes]:
        def need(count):
            while len(self._buffer) < count:
                chunk = self.sock.recv(65536)
                if not chunk:
                    raise ConnectionError("closed")
                self._buffer += chunk
        need(2)
        opcode, n = self._buffer[0] & 0x0F, self._buffer[1] & 0x7F
        at = 2
        if n == 126:
            need(4)
            n, at = struct.unpack(">H", self._buffer[2:4])[0], 4
        elif n == 127:
            need(10)
            n, at = struct.unpack(">Q", self._buffer[2:10])[0], 10
        need(at + n)
        payload, self._buffer = self._buffer[at:at + n], self._buffer[at + n:]
        return opcode, payload

    def channels(self) -> dict:
        """Read until the server has advertised its channels: topic → channel id."""
        found = {}
        while not found:
            opcode, payload = self._frame()
            if opcode == 1:
                message = json.loads(payload)
                if message.get("op") == "advertise":
                    found = {c["topic"]: c["id"] for c in message["channels"]}
        return found

    def subscribe(self, ids, first: int = 0) -> None:
        self.send_text(json.dumps({"op": "subscribe", "subscriptions": [
            {"id": first + i, "channelId": channel} for i, channel in enumerate(ids)]}))

    def unsubscribe(self, subscription_ids) -> None:
        self.send_text(json.dumps({"op": "unsubscribe",
                                   "subscriptionIds": list(subscription_ids)}))

    def messages(self, until):
        """Read binary message frames (opcode 1 of the protocol: subscription id, log time,
        payload) until ``until(subscription_id)`` returns True; yields each subscription id."""
        while True:
            opcode, payload = self._frame()
            if opcode == 2 and payload[:1] == b"\x01":
                subscription = struct.unpack("<I", payload[1:5])[0]
                yield subscription
                if until(subscription):
                    return

    def close(self) -> None:
        self.sock.close()


def queued(local_port: int, remote_port: int) -> tuple[int, int] | None:
    """(tx_queue, rx_queue) bytes of the TCP socket local_port → remote_port on 127.0.0.1, from
    /proc/net/tcp, or None when there is none."""
    for line in Path("/proc/net/tcp").read_text().splitlines()[1:]:
        fields = line.split()
        local, remote = fields[1], fields[2]
        if int(local.split(":")[1], 16) == local_port and \
                int(remote.split(":")[1], 16) == remote_port:
            tx, rx = fields[4].split(":")
            return int(tx, 16), int(rx, 16)
    return None


def stalled(client: RawClient) -> bool:
    """The server has bytes queued for ``client`` that the client's full window does not take:
    what a client that stopped reading looks like to the server's kernel."""
    server_side = queued(client.server_port, client.port)
    return server_side is not None and server_side[0] > 0
