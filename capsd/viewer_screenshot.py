"""`capsd render screenshot`: a real viewer's picture of a recording in the shipped layout.

A web build of an open-source Foxglove-compatible viewer (Lichtblick) opens a recording and a
layout from URLs (`?ds=remote-file&ds.url=...&layoutUrl=...&time=...`), or a live
`capsd live-view` (`ds=foxglove-websocket`). This module serves the recording (with HTTP
Range requests, which the viewer reads MCAP by), the layout and,
optionally, the viewer's own built files, from one loopback HTTP server, then has a headless
Chromium load that URL and, after a wait in real time, capture what it shows (over the
DevTools protocol on a loopback port). Nothing here draws: what comes out is the
viewer's rendering of our channels, schemas and layout.
"""

from __future__ import annotations

import base64
import json
import mimetypes
import re
import shutil
import subprocess
import tempfile
import threading
import time
import urllib.request
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import UTC, datetime
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import quote, unquote, urlsplit

from capsd.errors import CapsdError

if TYPE_CHECKING:
    from websockets.sync.client import ClientConnection

RECORDING_PATH = "/capsd/recording.mcap"
LAYOUT_PATH = "/capsd/capsd-layout.json"
# What the viewer reads across origins when it is served elsewhere (`--viewer-url`).
EXPOSED = "Accept-Ranges, Content-Length, Content-Range, ETag, Last-Modified"
CHUNK = 1 << 16
_RANGE = re.compile(r"^bytes=(\d*)-(\d*)$")
# Chromium on a closed network: no background connections, a fresh profile, software WebGL.
CHROMIUM_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--hide-scrollbars",
)


@dataclass(frozen=True)
class Served:
    """What the server hands out: two files by fixed paths, and a folder's files (or none)."""

    recording: Path | None  # None: a live source, nothing to serve
    layout: Path
    viewer_dir: Path | None = None

    def resolve(self, url_path: str) -> Path | None:
        """The file behind a request path; None for anything outside what is served."""
        path = unquote(urlsplit(url_path).path)
        if path == RECORDING_PATH and self.recording is not None:
            return self.recording
        if path == LAYOUT_PATH:
            return self.layout
        if self.viewer_dir is None:
            return None
        root = self.viewer_dir.resolve()
        wanted = (root / path.lstrip("/")).resolve()
        if wanted != root and root not in wanted.parents:
            return None  # ../ out of the viewer's folder
        if wanted.is_dir():
            wanted = wanted / "index.html"
        return wanted if wanted.is_file() else None


def byte_range(header: str | None, size: int) -> tuple[int, int] | None:
    """The inclusive (first, last) byte a Range header asks for; None: the whole file.

    Raises ValueError for a range that cannot be satisfied (answered 416).
    """
    if header is None:
        return None
    match = _RANGE.match(header.strip())
    if match is None or match.group(1) == match.group(2) == "":
        raise ValueError(f"unsupported Range {header!r}")
    first_s, last_s = match.groups()
    if first_s == "":  # the last N bytes
        n = int(last_s)
        if n == 0:
            raise ValueError(f"empty Range {header!r}")
        return max(size - n, 0), size - 1
    first = int(first_s)
    last = size - 1 if last_s == "" else min(int(last_s), size - 1)
    if first >= size or last < first:
        raise ValueError(f"Range {header!r} outside {size} bytes")
    return first, last


def _handler(served: Served) -> type[BaseHTTPRequestHandler]:
    class Handler(BaseHTTPRequestHandler):
        def log_message(self, format: str, *args: object) -> None:
            pass  # the viewer fetches hundreds of files: no line each

        def _cors(self) -> None:
            self.send_header("Access-Control-Allow-Origin", "*")
            self.send_header("Access-Control-Allow-Headers", "Range")
            self.send_header("Access-Control-Expose-Headers", EXPOSED)

        def do_OPTIONS(self) -> None:
            self.send_response(HTTPStatus.NO_CONTENT)
            self._cors()
            self.send_header("Access-Control-Allow-Methods", "GET, HEAD, OPTIONS")
            self.end_headers()

        def do_HEAD(self) -> None:
            self._send(body=False)

        def do_GET(self) -> None:
            self._send(body=True)

        def _send(self, *, body: bool) -> None:
            path = served.resolve(self.path)
            if path is None:
                self.send_error(HTTPStatus.NOT_FOUND)
                return
            size = path.stat().st_size
            try:
                span = byte_range(self.headers.get("Range"), size)
            except ValueError:
                self.send_response(HTTPStatus.REQUESTED_RANGE_NOT_SATISFIABLE)
                self._cors()
                self.send_header("Content-Range", f"bytes */{size}")
                self.end_headers()
                return
            first, last = span if span is not None else (0, size - 1)
            self.send_response(HTTPStatus.OK if span is None else HTTPStatus.PARTIAL_CONTENT)
            self._cors()
            kind = mimetypes.guess_type(path.name)[0] or "application/octet-stream"
            self.send_header("Content-Type", kind)
            self.send_header("Accept-Ranges", "bytes")
            self.send_header("Content-Length", str(max(last - first + 1, 0)))
            self.send_header("ETag", f'"{size}-{path.stat().st_mtime_ns}"')
            self.send_header("Cache-Control", "no-store")
            if span is not None:
                self.send_header("Content-Range", f"bytes {first}-{last}/{size}")
            self.end_headers()
            if not body:
                return
            with path.open("rb") as stream:
                stream.seek(first)
                left = last - first + 1
                try:
                    while left > 0:
                        chunk = stream.read(min(CHUNK, left))
                        if not chunk:
                            break
                        self.wfile.write(chunk)
                        left -= len(chunk)
                except (BrokenPipeError, ConnectionResetError):
                    pass  # the viewer cancels its first GET once it has the headers

    return Handler


@contextmanager
def serving(served: Served) -> Iterator[str]:
    """A loopback HTTP server for `served` while the block runs; yields its base URL."""
    for path, what in ((served.recording, "recording"), (served.layout, "layout")):
        if path is not None and not path.is_file():
            raise CapsdError(f"{path}: no such {what} file")
    if served.viewer_dir is not None and not (served.viewer_dir / "index.html").is_file():
        raise CapsdError(f"{served.viewer_dir}: no index.html (a viewer's web build?)")
    server = ThreadingHTTPServer(("127.0.0.1", 0), _handler(served))
    server.daemon_threads = True
    thread = threading.Thread(target=server.serve_forever, name="viewer-http", daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}"
    finally:
        server.shutdown()
        server.server_close()
        thread.join()


def rfc3339(stamp_ns: int) -> str:
    """A stamp as the viewer's `time` parameter (UTC, nanoseconds)."""
    seconds, nanos = divmod(stamp_ns, 1_000_000_000)
    day = datetime.fromtimestamp(seconds, UTC).strftime("%Y-%m-%dT%H:%M:%S")
    return f"{day}.{nanos:09d}Z"


def viewer_url(viewer: str, base: str, *, time_ns: int | None, live: str | None = None) -> str:
    """The viewer's URL that opens our layout and the served recording at `time_ns`.

    With `live` (a `capsd live-view` WebSocket URL), that instead of a recording.
    """
    params = {"layoutUrl": f"{base}{LAYOUT_PATH}"}
    if live is None:
        params |= {"ds": "remote-file", "ds.url": f"{base}{RECORDING_PATH}"}
    else:
        params |= {"ds": "foxglove-websocket", "ds.url": live}
    if time_ns is not None:
        params["time"] = rfc3339(time_ns)
    query = "&".join(f"{k}={quote(v, safe='')}" for k, v in params.items())
    return f"{viewer.rstrip('/')}/?{query}"


def find_browser(browser: str | None) -> str:
    """The Chromium to run: the one named, else the first of the usual names on PATH."""
    names = [browser] if browser else ["chromium", "chromium-browser", "google-chrome"]
    for name in names:
        found = shutil.which(name)
        if found:
            return found
    raise CapsdError(
        f"no browser {'named ' + browser if browser else '(chromium) on PATH'}: "
        "install Chromium (Debian: apt install chromium) or name one with --browser"
    )


def screenshot(
    url: str,
    out: Path,
    *,
    browser: str,
    width: int,
    height: int,
    wait_s: float,
    progress: Callable[[float], None] | None = None,
) -> None:
    """Chromium, headless, loads `url`; what it shows after `wait_s` (real time) goes to `out`.

    Driven over the DevTools protocol (a loopback port Chromium picks), so the wait is the
    page's real time: the viewer reads the recording in the background while it draws.
    """
    try:
        from websockets.sync.client import connect
    except ImportError:
        raise CapsdError("needs the websockets package (install capsd[topside])") from None

    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="capsd-chromium-") as profile:
        # Chromium's chatter to a file: a pipe nobody reads fills up and stalls it.
        log = Path(profile) / "chromium.log"
        command = [
            browser,
            *CHROMIUM_FLAGS,
            f"--user-data-dir={profile}",
            f"--window-size={width},{height}",
            "--remote-debugging-address=127.0.0.1",
            "--remote-debugging-port=0",
            url,
        ]
        with (
            log.open("w") as log_file,
            subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=log_file) as chromium,
        ):
            try:
                port = _devtools_port(Path(profile), chromium, log)
                page = _page_socket(port)
                with connect(page, max_size=None, open_timeout=10) as socket:
                    # The page exactly this size (a headless window's size includes its frame).
                    _call(
                        socket,
                        1,
                        "Emulation.setDeviceMetricsOverride",
                        {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False},
                    )
                    started = time.monotonic()
                    while (waited := time.monotonic() - started) < wait_s:
                        if progress is not None:
                            progress(waited)
                        time.sleep(min(1.0, wait_s - waited))
                    reply = _call(socket, 2, "Page.captureScreenshot", {"format": "png"})
                if "result" not in reply:
                    raise CapsdError(f"{browser}: no screenshot ({reply.get('error')})")
                out.write_bytes(base64.b64decode(reply["result"]["data"]))
            except (OSError, TimeoutError) as exc:
                raise CapsdError(f"{browser}: {exc}") from exc
            finally:
                chromium.terminate()
                try:
                    chromium.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    chromium.kill()


def _call(socket: ClientConnection, call_id: int, method: str, params: dict[str, Any]) -> Any:
    """One DevTools command and its reply (events in between are skipped)."""
    socket.send(json.dumps({"id": call_id, "method": method, "params": params}))
    while True:
        reply = json.loads(socket.recv(timeout=60))
        if reply.get("id") == call_id:
            return reply


def _devtools_port(profile: Path, chromium: subprocess.Popen[bytes], log: Path) -> int:
    """The DevTools port Chromium chose (it writes it into its profile), within 30 s."""
    marker = profile / "DevToolsActivePort"
    deadline = time.monotonic() + 30.0
    while time.monotonic() < deadline:
        if chromium.poll() is not None:
            tail = log.read_text(errors="replace").strip().splitlines()[-3:]
            raise CapsdError(f"chromium exited {chromium.returncode}: {' / '.join(tail)}")
        if marker.is_file():
            first = marker.read_text().splitlines()[:1]
            if first and first[0].isdigit():
                return int(first[0])
        time.sleep(0.1)
    raise CapsdError("chromium did not open its DevTools port within 30 s")


def _page_socket(port: int) -> str:
    """The DevTools WebSocket of the page Chromium opened."""
    deadline = time.monotonic() + 30.0
    while time.monotonic() < deadline:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=5) as reply:
            targets = json.loads(reply.read())
        pages = [t for t in targets if t.get("type") == "page"]
        if pages:
            return str(pages[0]["webSocketDebuggerUrl"])
        time.sleep(0.2)
    raise CapsdError("chromium opened no page within 30 s")
