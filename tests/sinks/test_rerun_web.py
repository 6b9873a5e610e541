"""The web viewer's server: loopback by default, a clear error on a busy port, stopped with its owner."""

from __future__ import annotations

import numpy as np
import pytest

from polcam.sinks.rerun import RerunSink
from polcam.sinks.rerun_web import WebServer, is_loopback


def test_is_loopback():
    assert is_loopback("127.0.0.1") and is_loopback("127.3.4.5") and is_loopback("::1") and is_loopback("localhost")
    assert not is_loopback("0.0.0.0") and not is_loopback("192.0.2.2") and not is_loopback("rig.example")


def _other_addresses() -> list[str]:
    """This machine's IPv4 addresses that are not loopback (``hostname -I``)."""
    import ipaddress
    import subprocess

    try:
        out = subprocess.run(["hostname", "-I"], capture_output=True, text=True, timeout=5).stdout
    except (OSError, subprocess.TimeoutExpired):
        return []
    addrs = []
    for a in out.split():
        try:
            ip = ipaddress.ip_address(a)
        except ValueError:
            continue
        if ip.version == 4 and not ip.is_loopback:
            addrs.append(a)
    return addrs


def _reachable(host: str, port: int) -> bool:
    import socket

    try:
        socket.create_connection((host, port), timeout=2).close()
        return True
    except OSError:
        return False


def test_the_web_viewer_listens_on_loopback_only_by_default():
    others = _other_addresses()
    if not others:
        pytest.skip("this machine has no non-loopback IPv4 address to try the ports from")
    with WebServer(port=0) as server:
        assert server.bind == "127.0.0.1" and server.url.startswith(f"http://127.0.0.1:{server.port}/?url=")
        for port in (server.port, server.grpc_port):
            assert _reachable("127.0.0.1", port)
            for addr in others:
                assert not _reachable(addr, port), (addr, port)
    # the check can fail: bound to every interface, the same ports are reachable from those addresses
    with WebServer(port=0, bind="0.0.0.0") as server:
        assert "anyone on the networks this machine is on can watch" in server.message()
        for port in (server.port, server.grpc_port):
            assert _reachable(others[0], port)
    assert not _reachable("127.0.0.1", server.port)  # stopped with the context


def test_serve_sink_streams_to_its_own_server_and_stops_it(tmp_path):
    import os

    sink = RerunSink("serve", port=0, view_scale=1.0)
    pid = sink.server.pid
    assert pid is not None and _reachable("127.0.0.1", sink.server.grpc_port)
    sink.log_polarization(0, None, s0=np.ones((4, 6), np.float32), dolp=np.zeros((4, 6), np.float32),
                          aolp=np.zeros((4, 6), np.float32))
    sink.close()
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)


def test_a_port_in_use_is_a_clear_error():
    import socket

    from polcam.errors import PolcamError
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    s.listen(1)
    port = s.getsockname()[1]
    try:
        with pytest.raises(PolcamError, match=f"did not start|did not open ports|{port}"):
            WebServer(port=port, start_timeout=10)
    finally:
        s.close()
