"""The live view for every Foxglove client: ``foxglove.websocket.v1`` beside the SDK's ``foxglove.sdk.v1``.

foxglove-sdk's server accepts only the subprotocols ``foxglove.sdk.v1`` (and ``.v1.1``) and answers HTTP 400
to anything else. Lichtblick, older Foxglove releases and every client built on npm's ``@foxglove/ws-protocol``
offer ``foxglove.websocket.v1``. The two are the same protocol under two names (Foxglove's own statement;
Lichtblick and Flora accept both for that reason), so the bridge here only renames: it listens where the
view was asked to listen, reads a client's WebSocket upgrade request, offers the SDK server (on a loopback
port of its own) ``foxglove.sdk.v1`` in place of ``foxglove.websocket.v1``, puts the client's name back into
the server's answer and then copies bytes both ways untouched. The WebSocket accept key depends on the
client's key alone, so the handshake stays valid.
"""

from __future__ import annotations

import logging
import re
import socket
import threading

log = logging.getLogger(f"sarbot.{__name__}")

SDK_SUBPROTOCOLS = ("foxglove.sdk.v1", "foxglove.sdk.v1.1")
LEGACY_SUBPROTOCOL = "foxglove.websocket.v1"
MAX_HEAD_BYTES = 16384  # an upgrade request is a few hundred bytes; more is not a WebSocket client
_PROTOCOL_HEADER = re.compile(rb"^(sec-websocket-protocol:[ \t]*)([^\r\n]*)\r\n", re.I | re.M)


def offered_subprotocols(head: bytes) -> list[str]:
    """The subprotocols an HTTP upgrade request's ``Sec-WebSocket-Protocol`` headers offer, in order."""
    return [p.strip() for m in _PROTOCOL_HEADER.finditer(head) for p in m.group(2).decode("latin-1").split(",")
            if p.strip()]


def request_for_sdk(head: bytes) -> tuple[bytes, bool]:
    """The request head to forward to the SDK server, and whether the answer must be renamed back.

    A client that offers an SDK subprotocol gets the SDK's answer unchanged; one that offers only
    ``foxglove.websocket.v1`` is offered to the server as ``foxglove.sdk.v1``; anything else passes as it
    is (and the server refuses it as it would without the bridge).
    """
    offered = offered_subprotocols(head)
    if any(p in SDK_SUBPROTOCOLS for p in offered) or LEGACY_SUBPROTOCOL not in offered:
        return head, False
    head = _PROTOCOL_HEADER.sub(lambda m: m.group(1) + SDK_SUBPROTOCOLS[0].encode() + b"\r\n", head, count=1)
    return _drop_repeated_protocol_headers(head), True


def _drop_repeated_protocol_headers(head: bytes) -> bytes:
    seen = False

    def keep_first(m: re.Match) -> bytes:
        nonlocal seen
        if seen:
            return b""
        seen = True
        return m.group(0)

    return _PROTOCOL_HEADER.sub(keep_first, head)


def answer_for_client(head: bytes) -> bytes:
    """The server's answer with the SDK's subprotocol name replaced by ``foxglove.websocket.v1``."""
    return _PROTOCOL_HEADER.sub(lambda m: m.group(1) + LEGACY_SUBPROTOCOL.encode() + b"\r\n", head, count=1)


def _read_head(sock: socket.socket) -> tuple[bytes, bytes]:
    """An HTTP head (up to and including the blank line) and whatever bytes followed it."""
    data = b""
    while b"\r\n\r\n" not in data:
        chunk = sock.recv(4096)
        if not chunk:
            raise ConnectionError("closed before the end of the HTTP head")
        data += chunk
        if len(data) > MAX_HEAD_BYTES:
            raise ConnectionError(f"HTTP head longer than {MAX_HEAD_BYTES} bytes")
    end = data.index(b"\r\n\r\n") + 4
    return data[:end], data[end:]


def _pump(src: socket.socket, dst: socket.socket) -> None:
    try:
        while chunk := src.recv(65536):
            dst.sendall(chunk)
    except OSError:
        pass
    finally:
        for s in (dst, src):
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass


class SubprotocolBridge:
    """Listens on ``(host, port)`` (port 0: any free one, see :attr:`port`) and serves every connection
    through the SDK server at ``127.0.0.1:sdk_port``, renaming the subprotocol where the client needs it."""

    def __init__(self, host: str, port: int, sdk_port: int):
        self.sdk_port = sdk_port
        try:
            self.listener = socket.create_server((host, port),
                                                 family=socket.AF_INET6 if ":" in host else socket.AF_INET)
        except OSError as e:
            from imaging.core.errors import SarbotError

            raise SarbotError(f"--view {host}:{port}: cannot listen there: {e.strerror}") from None
        self.port = self.listener.getsockname()[1]
        self.renamed = 0  # connections served as foxglove.websocket.v1
        self._stopping = False
        self._thread = threading.Thread(target=self._accept, name="view-subprotocols", daemon=True)
        self._thread.start()

    def _accept(self) -> None:
        while not self._stopping:
            try:
                client, _ = self.listener.accept()
            except OSError:
                return
            threading.Thread(target=self._serve, args=(client,), name="view-connection", daemon=True).start()

    def _serve(self, client: socket.socket) -> None:
        server = None
        try:
            client.settimeout(10.0)
            head, rest = _read_head(client)
            head, rename = request_for_sdk(head)
            server = socket.create_connection(("127.0.0.1", self.sdk_port), timeout=10.0)
            server.sendall(head + rest)
            answer, rest = _read_head(server)
            if rename and answer.startswith(b"HTTP/1.1 101"):
                answer = answer_for_client(answer)
                self.renamed += 1
            client.sendall(answer + rest)
            client.settimeout(None)
            server.settimeout(None)
        except (OSError, ConnectionError) as e:
            log.debug("live view: a connection ended in its handshake: %s", e)
            for s in (client, server):
                if s is not None:
                    s.close()
            return
        upstream = threading.Thread(target=_pump, args=(client, server), name="view-upstream", daemon=True)
        upstream.start()
        _pump(server, client)
        upstream.join(5.0)
        client.close()
        server.close()

    def stop(self) -> None:
        self._stopping = True
        try:
            self.listener.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self.listener.close()
        self._thread.join(2.0)
