"""The viewer's server answers only requests whose ``Host`` is the address it serves on (issue
33, item 6): a page of another site that DNS rebinding points at 127.0.0.1 gets 403."""

from __future__ import annotations

import socket

import pytest

from sparsebtf.rendering.viewer import ViewerBundle, host_allowed, host_names, serve

MANIFEST = {"data": "data.bin"}


def raw_get(port: int, host: str | None, path: str = "/manifest.json") -> tuple[int, bytes]:
    """Status and body of one GET sent byte for byte (``host=None``: no Host header)."""
    lines = [f"GET {path} HTTP/1.1"] + ([f"Host: {host}"] if host is not None else [])
    request = ("\r\n".join([*lines, "Connection: close", "", ""])).encode()
    with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
        s.sendall(request)
        reply = b""
        while chunk := s.recv(65536):
            reply += chunk
    head, _, body = reply.partition(b"\r\n\r\n")
    return int(head.split()[1]), body


@pytest.fixture(scope="module")
def server():
    with serve(ViewerBundle(dict(MANIFEST), b"\x00" * 64)) as srv:
        yield srv


@pytest.mark.parametrize("name", ["127.0.0.1", "localhost", "LOCALHOST"])
def test_loopback_names_with_the_served_port_are_answered(server, name) -> None:
    status, body = raw_get(server.port, f"{name}:{server.port}")
    assert status == 200 and b'"data.bin"' in body


@pytest.mark.parametrize(
    "host",
    [
        "evil.example:{port}",  # a rebound name, the right port
        "evil.example",
        "127.0.0.1:1",  # another port
        "127.0.0.1",  # port 80 implied
        "localhost.evil.example:{port}",
        "127.0.0.1:{port}x",
        "",
        None,  # no Host at all
    ],
)
def test_other_hosts_get_403_with_a_short_body(server, host) -> None:
    status, body = raw_get(server.port, None if host is None else host.format(port=server.port))
    assert status == 403
    assert body.decode().strip() == f"403: this viewer answers requests for {server.url} only"
    assert b"data.bin" not in body


def test_every_file_is_guarded(server) -> None:
    for path in ("/", "/index.html", "/data.bin", "/nope"):
        assert raw_get(server.port, f"evil.example:{server.port}", path)[0] == 403
    assert raw_get(server.port, f"127.0.0.1:{server.port}", "/nope")[0] == 404


def test_host_rules() -> None:
    loop = host_names("127.0.0.1", "127.0.0.1")
    assert {"localhost", "127.0.0.1", "::1"} <= loop
    assert host_allowed("[::1]:8000", loop, 8000, "127.0.0.1")
    assert not host_allowed("[::1]x:8000", loop, 8000, "127.0.0.1")
    assert host_allowed("localhost:80", loop, 80, "127.0.0.1")
    assert host_allowed("localhost", loop, 80, "127.0.0.1")
    # Beyond loopback: the address served on and the IP the connection arrived on; no
    # localhost (a bind to one LAN address is not reachable as localhost).
    lan = host_names("192.168.1.20", "192.168.1.20")
    assert "localhost" not in lan
    assert host_allowed("192.168.1.20:9000", lan, 9000, "192.168.1.20")
    assert not host_allowed("attacker.example:9000", lan, 9000, "192.168.1.20")
    every = host_names("0.0.0.0", "0.0.0.0")
    assert host_allowed("10.1.2.3:9000", every, 9000, "10.1.2.3")  # the interface used
    assert not host_allowed("10.9.9.9:9000", every, 9000, "10.1.2.3")
    assert host_allowed(f"{socket.gethostname()}:9000", every, 9000, "10.1.2.3")
