"""Rerun's web viewer and its data server, bound to one address, as a child process.

Rerun's Python SDK serves the web viewer's page on every interface and has no
option to narrow it; the Rerun command-line tool shipped with rerun-sdk
(``rerun --serve-web --bind ADDR``) binds both the page and the data (gRPC)
server to one address.  :class:`WebServer` runs that tool as a child process
bound to 127.0.0.1 unless told otherwise; :class:`polcam.sinks.rerun.RerunSink`
(``serve``) streams to it, ``polcam view --web`` streams to it or has it load
an ``.rrd``.
"""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.parse
from pathlib import Path

from polcam.errors import PolcamError

__all__ = ["LOOPBACK", "WebServer", "check_port_free", "has_display", "is_loopback", "listening_owner",
           "native_viewer", "rerun_executable"]


#: The default address of the web viewer: this machine only.
LOOPBACK = "127.0.0.1"


def is_loopback(address: str) -> bool:
    """True for an address only this machine can reach (127.0.0.0/8, ::1, localhost)."""
    import ipaddress

    if address == "localhost":
        return True
    try:
        return ipaddress.ip_address(address).is_loopback
    except ValueError:
        return False


def rerun_executable() -> str:
    """The Rerun command-line tool shipped with rerun-sdk (its ``rerun_cli`` package)."""
    try:
        import rerun_cli

        exe = Path(rerun_cli.__file__).parent / "rerun"
        if exe.is_file():
            return str(exe)
    except ImportError:
        pass
    import shutil

    found = shutil.which("rerun")
    if found is None:
        raise PolcamError("the Rerun command-line tool (rerun-sdk's rerun_cli) is not installed")
    return found


def _free_ports(n: int) -> list[int]:
    socks = []
    try:
        for _ in range(n):
            s = socket.socket()
            s.bind((LOOPBACK, 0))
            socks.append(s)
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


def check_port_free(bind: str, port: int) -> None:
    """Refuse a port something already listens on, before any server starts.

    Binds a probe socket to (``bind``, ``port``) with ``SO_REUSEADDR`` (as a
    server does): that fails only when the port is held, e.g. by another
    polcam view or Rerun viewer.  An address this machine does not have is
    left to the server's own error.

    Raises
    ------
    PolcamError
        The port is in use (named, with what to do).
    """
    import errno

    family = socket.AF_INET6 if ":" in bind else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind((bind, int(port)))
        except OSError as exc:
            if exc.errno != errno.EADDRINUSE:
                return
            raise PolcamError(f"port {port} is in use: something is already listening on {bind}:{port} (another "
                              "polcam view or Rerun viewer?); choose another --port (the data use port + 1), "
                              "or --port 0 for free ones") from None


def _listening_inodes(port: int) -> set[int] | None:
    """Inodes of the TCP sockets listening on ``port`` (Linux ``/proc/net/tcp*``); None elsewhere."""
    found: set[int] = set()
    seen = False
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            lines = Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        seen = True
        for line in lines:
            f = line.split()
            if len(f) > 9 and f[3] == "0A" and int(f[1].rsplit(":", 1)[1], 16) == int(port):  # 0A: LISTEN
                found.add(int(f[9]))
    return found if seen else None


def listening_owner(pid: int, port: int) -> bool | None:
    """Whether process ``pid`` holds a socket listening on ``port``; None where that cannot be read.

    Linux only: the listening sockets' inodes (``/proc/net/tcp``, ``tcp6``)
    against the process's open files (``/proc/PID/fd``).
    """
    import os

    inodes = _listening_inodes(port)
    if inodes is None:
        return None
    targets = {f"socket:[{i}]" for i in inodes}
    try:
        fds = os.listdir(f"/proc/{pid}/fd")
    except OSError:
        return None if not Path("/proc/self/fd").is_dir() else False
    for fd in fds:
        try:
            if os.readlink(f"/proc/{pid}/fd/{fd}") in targets:
                return True
        except OSError:
            continue
    return False


def _die_with_parent() -> None:  # runs in the child between fork and exec
    import ctypes

    ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG


class WebServer:
    """Rerun's web viewer and its data server, bound to one address, as a child process.

    Parameters
    ----------
    bind
        Address to listen on (default 127.0.0.1: this machine only; 0.0.0.0
        opens it to every network this machine is on).
    port
        Port of the web page; the data (gRPC) port is ``port + 1``.  0 picks
        two free ports.  A port something already listens on is refused
        before the server starts (:func:`check_port_free`), and the server is
        ready only once the process started here holds both ports (Linux), so
        polcam never streams into another server that answers there.
    recordings
        ``.rrd`` files the server loads and serves.
    memory_limit
        Data kept for viewers that connect later (oldest dropped first), e.g.
        ``"1GiB"`` or ``"25%"``.
    start_timeout
        Seconds to wait for both ports to accept connections.

    Attributes
    ----------
    url
        The page to open in a browser (it connects the viewer to the data).
    grpc_url
        Where an SDK streams data to (``rerun+http://.../proxy``).

    Notes
    -----
    The child gets SIGTERM when the thread that started it ends (Linux
    ``PR_SET_PDEATHSIG``), so no server outlives polcam even when it is killed.
    """

    def __init__(self, *, bind: str = LOOPBACK, port: int = 9090, recordings: tuple[str | Path, ...] = (),
                 memory_limit: str = "1GiB", start_timeout: float = 30.0) -> None:
        if not 0 <= int(port) <= 65534:
            raise PolcamError(f"port {port!r}: expected 0 (any free port) or 1..65534 (the data use port + 1)")
        web, grpc = _free_ports(2) if int(port) == 0 else (int(port), int(port) + 1)
        if int(port) != 0:
            for p in (web, grpc):
                check_port_free(str(bind), p)
        self.bind = str(bind)
        self.port, self.grpc_port = web, grpc
        host = LOOPBACK if self.bind in ("0.0.0.0", "::", "127.0.0.1") else self.bind
        self._probe = host if is_loopback(host) or self.bind not in ("0.0.0.0", "::") else LOOPBACK
        public = host if self.bind not in ("0.0.0.0", "::") else socket.gethostname()
        url_host = f"[{public}]" if ":" in public else public
        self.grpc_url = f"rerun+http://{'[' + host + ']' if ':' in host else host}:{grpc}/proxy"
        viewer_data = f"rerun+http://{url_host}:{grpc}/proxy"
        self.url = f"http://{url_host}:{web}/?url={urllib.parse.quote(viewer_data, safe='')}"
        cmd = [rerun_executable(), "--serve-web", "--bind", self.bind, "--port", str(grpc),
               "--web-viewer-port", str(web), "--server-memory-limit", str(memory_limit)]
        if not is_loopback(self.bind):
            # the data server lets only pages from localhost read it; a browser on another machine
            # loads the page from this machine's name or address, on the web viewer's port
            cmd += ["--cors-allow-origin", f"http://*:{web}"]
        cmd += [str(Path(r)) for r in recordings]
        self._drain: threading.Thread | None = None
        self._proc: subprocess.Popen[bytes] | None = subprocess.Popen(
            cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
            preexec_fn=_die_with_parent if sys.platform.startswith("linux") else None)
        try:
            self._wait_ready(start_timeout)
        except BaseException:
            self.stop()
            raise

    @property
    def pid(self) -> int | None:
        """Process id of the server (None once stopped)."""
        return None if self._proc is None else self._proc.pid

    def _wait_ready(self, timeout: float) -> None:
        end = time.monotonic() + timeout
        pending = {self.port, self.grpc_port}
        while pending:
            assert self._proc is not None
            if self._proc.poll() is not None:
                err = (self._proc.stderr.read() if self._proc.stderr else b"").decode(errors="replace")
                lines = [x for x in err.splitlines() if "ERROR" in x or "rror" in x] or err.splitlines()[-3:]
                raise PolcamError(f"the Rerun web viewer on {self.bind}:{self.port}/{self.grpc_port} did not "
                                  f"start (ports in use? try --port): {' '.join(lines)[-400:]}")
            for p in list(pending):
                try:
                    socket.create_connection((self._probe, p), timeout=0.5).close()
                except OSError:
                    continue
                # something answers: it must be the server started here, not one already there
                if listening_owner(self._proc.pid, p) is not False:
                    pending.discard(p)
            if pending:
                if time.monotonic() > end:
                    raise PolcamError(f"the Rerun web viewer did not open ports {sorted(pending)} in {timeout:.0f} s "
                                      "(or another program holds them: try --port)")
                time.sleep(0.1)
        if self._proc is not None and self._proc.stderr is not None:
            # keep draining its log so the child never blocks on a full pipe
            self._drain = threading.Thread(target=self._proc.stderr.read, daemon=True)
            self._drain.start()

    def message(self) -> str:
        """What to tell the user: the URL to open, and who else can open it."""
        text = f"Rerun web viewer: open {self.url}"
        if not is_loopback(self.bind):
            text += (f"\nwarning: listening on {self.bind} (ports {self.port} and {self.grpc_port}): anyone on "
                     "the networks this machine is on can watch (use --bind 127.0.0.1 for this machine only)")
        else:
            text += " (this machine only; --bind ADDR to open it to a network)"
        return text

    def stop(self) -> None:
        """Stop the server (SIGTERM, then SIGKILL after 5 s) and wait for it."""
        proc, self._proc = self._proc, None
        if proc is None:
            return
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        if self._drain is not None:
            self._drain.join(5)
            self._drain = None
        if proc.stderr is not None:
            proc.stderr.close()

    def __enter__(self) -> WebServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def has_display() -> bool:
    """Whether a native window can open here: an X11 or Wayland display on Linux (elsewhere: yes)."""
    import os

    if not sys.platform.startswith("linux"):
        return True
    return any(os.environ.get(v) for v in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET"))


def native_viewer(*, recordings: tuple[str | Path, ...] = (), bind: str = LOOPBACK,
                  memory_limit: str = "75%", start_timeout: float = 30.0) -> str:
    """Start Rerun's native viewer, its data server bound to ``bind``; returns the URL to stream to.

    The SDK's own ``spawn`` starts the viewer listening on every interface; the
    viewer started here listens on ``bind`` (this machine only by default) on a
    free port.  It is the user's window: it stays open after polcam ends.

    Raises
    ------
    PolcamError
        No display to open a window on (with the flag that serves the viewer
        to a browser instead), or the viewer did not start.
    """
    if not has_display():
        raise PolcamError("no display to open the native Rerun viewer on (DISPLAY and WAYLAND_DISPLAY "
                          "are unset): use the web viewer instead (polcam view --web, "
                          "polcam capture --rerun serve) and open the URL it prints")
    (port,) = _free_ports(1)
    cmd = [rerun_executable(), "--bind", str(bind), "--port", str(port), "--memory-limit", str(memory_limit),
           *[str(Path(r)) for r in recordings]]
    proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    probe = LOOPBACK if bind in ("0.0.0.0", "::") or is_loopback(bind) else bind
    end = time.monotonic() + start_timeout
    while True:
        if proc.poll() is not None:
            raise PolcamError(f"the native Rerun viewer exited with status {proc.returncode} before it "
                              "opened (no usable display or graphics driver?)")
        try:
            socket.create_connection((probe, port), timeout=0.5).close()
            break
        except OSError:
            if time.monotonic() > end:
                proc.terminate()
                raise PolcamError(f"the native Rerun viewer did not open port {port} in {start_timeout:.0f} s")
            time.sleep(0.1)
    host = f"[{probe}]" if ":" in probe else probe
    return f"rerun+http://{host}:{port}/proxy"
