"""The viewer screenshot's server: what a web viewer fetches, over real HTTP on loopback."""

from __future__ import annotations

import urllib.error
import urllib.request
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

import pytest
from hypothesis import given
from hypothesis import strategies as st
from mcap.writer import Writer

from capsd.errors import CapsdError
from capsd.recording import time_span_ns
from capsd.viewer_screenshot import (
    LAYOUT_PATH,
    RECORDING_PATH,
    Served,
    byte_range,
    rfc3339,
    serving,
    viewer_url,
)


def _recording(path: Path, stamps_ns: list[int]) -> Path:
    with path.open("wb") as stream:
        writer = Writer(stream)
        writer.start()
        schema = writer.register_schema("s", "jsonschema", b"{}")
        channel = writer.register_channel("/x", "json", schema)
        for k, stamp in enumerate(stamps_ns):
            writer.add_message(channel, stamp, b'{"k": %d}' % k, stamp)
        writer.finish()  # type: ignore[no-untyped-call]
    return path


def _get(url: str, headers: dict[str, str] | None = None) -> tuple[int, dict[str, str], bytes]:
    request = urllib.request.Request(url, headers=headers or {})
    try:
        with urllib.request.urlopen(request, timeout=10) as response:
            return response.status, dict(response.headers), response.read()
    except urllib.error.HTTPError as exc:
        return exc.code, dict(exc.headers), b""


def test_serves_the_recording_by_ranges_the_layout_and_the_viewer(tmp_path: Path) -> None:
    recording = _recording(tmp_path / "demo.mcap", [1_000_000_000 + k * 10**8 for k in range(50)])
    layout = tmp_path / "layout.json"
    layout.write_text('{"configById": {}}')
    viewer = tmp_path / "viewer"
    (viewer / "js").mkdir(parents=True)
    (viewer / "index.html").write_text("<html>viewer</html>")
    (viewer / "js" / "main.js").write_text("1;")
    (tmp_path / "secret.txt").write_text("not served")
    data = recording.read_bytes()
    with serving(Served(recording, layout, viewer)) as base:
        assert base.startswith("http://127.0.0.1:")
        # The viewer's first GET: the whole file, with what it needs to read by ranges.
        status, headers, body = _get(base + RECORDING_PATH)
        assert (status, body) == (200, data)
        assert headers["Accept-Ranges"] == "bytes"
        assert headers["Content-Length"] == str(len(data))
        assert headers["Access-Control-Allow-Origin"] == "*"
        assert "Content-Range" in headers["Access-Control-Expose-Headers"]
        for header, want in (
            ("bytes=0-7", data[:8]),
            ("bytes=10-", data[10:]),
            ("bytes=-16", data[-16:]),
            (f"bytes=5-{len(data) + 100}", data[5:]),
        ):
            status, headers, body = _get(base + RECORDING_PATH, {"Range": header})
            assert status == 206, header
            assert body == want, header
            assert headers["Content-Range"].endswith(f"/{len(data)}")
        status, headers, _ = _get(base + RECORDING_PATH, {"Range": f"bytes={len(data)}-"})
        assert status == 416
        assert headers["Content-Range"] == f"bytes */{len(data)}"
        assert _get(base + LAYOUT_PATH)[2] == layout.read_bytes()
        assert _get(base + "/")[2] == b"<html>viewer</html>"
        assert _get(base + "/js/main.js")[2] == b"1;"
        # Nothing else: not a file beside the viewer, not a missing one.
        assert _get(base + "/../secret.txt")[0] == 404
        assert _get(base + "/%2e%2e/secret.txt")[0] == 404
        assert _get(base + "/nothing.js")[0] == 404


def test_names_what_is_missing(tmp_path: Path) -> None:
    layout = tmp_path / "layout.json"
    layout.write_text("{}")
    with (
        pytest.raises(CapsdError, match="no such recording file"),
        serving(Served(tmp_path / "none.mcap", layout)),
    ):
        pass
    recording = _recording(tmp_path / "r.mcap", [5])
    with (
        pytest.raises(CapsdError, match=r"no index\.html"),
        serving(Served(recording, layout, tmp_path)),
    ):
        pass
    with pytest.raises(CapsdError, match="not a readable MCAP"):
        time_span_ns(layout)


def test_the_viewer_url_opens_our_recording_layout_and_time(tmp_path: Path) -> None:
    stamps = [1_700_000_000_123_456_789, 1_700_000_030_000_000_000]
    first, last = time_span_ns(_recording(tmp_path / "r.mcap", stamps))
    assert (first, last) == tuple(stamps)
    url = viewer_url("http://127.0.0.1:9/app/", "http://127.0.0.1:8", time_ns=first)
    parts = urlsplit(url)
    assert parts.path == "/app/"
    query = {k: v[0] for k, v in parse_qs(parts.query).items()}
    assert query == {
        "ds": "remote-file",
        "ds.url": "http://127.0.0.1:8" + RECORDING_PATH,
        "layoutUrl": "http://127.0.0.1:8" + LAYOUT_PATH,
        "time": "2023-11-14T22:13:20.123456789Z",
    }
    assert rfc3339(0) == "1970-01-01T00:00:00.000000000Z"
    # A live view instead: the viewer connects to its WebSocket; nothing but the layout served.
    live = viewer_url("http://v", "http://127.0.0.1:8", time_ns=None, live="ws://127.0.0.1:8765")
    query = {k: v[0] for k, v in parse_qs(urlsplit(live).query).items()}
    assert query == {
        "ds": "foxglove-websocket",
        "ds.url": "ws://127.0.0.1:8765",
        "layoutUrl": "http://127.0.0.1:8" + LAYOUT_PATH,
    }
    layout = tmp_path / "layout.json"
    layout.write_text("{}")
    with serving(Served(None, layout)) as base:
        assert _get(base + LAYOUT_PATH)[2] == b"{}"
        assert _get(base + RECORDING_PATH)[0] == 404


@given(size=st.integers(1, 10_000), a=st.integers(0, 12_000), b=st.integers(0, 12_000))
def test_byte_ranges_stay_inside_the_file(size: int, a: int, b: int) -> None:
    for header in (f"bytes={a}-{b}", f"bytes={a}-", f"bytes=-{b}"):
        try:
            span = byte_range(header, size)
        except ValueError:
            continue
        assert span is not None
        first, last = span
        assert 0 <= first <= last < size
    assert byte_range(None, size) is None
    with pytest.raises(ValueError, match="unsupported"):
        byte_range("bytes=1-2,5-6", size)
