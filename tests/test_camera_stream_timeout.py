"""A camera URL that does not answer (a stream server that accepts and then says nothing, on localhost) is
refused within the stream timeout, with a message that says so: OpenCV's FFmpeg backend waited 30 s, silent."""

import socket
import threading
import time

import pytest

from cell.errors import BadInput
from cell.vision.sources import open_camera


@pytest.fixture
def silent_server():
    """A TCP server on 127.0.0.1 that accepts every connection and never answers."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(8)
    held = []

    def accept():
        while True:
            try:
                held.append(server.accept()[0])
            except OSError:
                return

    threading.Thread(target=accept, daemon=True).start()
    yield server.getsockname()[1]
    server.close()
    for c in held:
        c.close()


def test_a_stream_that_never_answers_is_refused_within_its_timeout(silent_server, monkeypatch):
    camera = open_camera(f"http://127.0.0.1:{silent_server}/video.mjpg")
    monkeypatch.setattr(camera, "STREAM_TIMEOUT_S", 1.0)
    t0 = time.monotonic()
    with pytest.raises(BadInput, match=r"cannot be opened \(no stream OpenCV reads answered within 1 s\)"):
        camera.connect()
    assert time.monotonic() - t0 < 15.0  # 30 s before: OpenCV's own wait (a loose bound, not a timing target)


def test_a_refused_address_is_not_blamed_on_a_timeout():
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(BadInput, match=r"cannot be opened \(no stream OpenCV reads there: the address refused"):
        open_camera(f"http://127.0.0.1:{port}/video.mjpg").connect()


def test_a_device_that_does_not_exist_is_not_blamed_on_a_timeout(capfd):
    with pytest.raises(BadInput, match=r"cannot be opened \(no such device"):
        open_camera("/dev/video99").connect()
    # the backends' own lines ("[ WARN:0@0.08] global cap_v4l.cpp:915 open VIDEOIO(V4L2:/dev/video99) ...") came
    # ahead of that one-line message
    assert "WARN" not in capfd.readouterr().err
