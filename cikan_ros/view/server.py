"""The view's HTTP server: the standard library's ThreadingHTTPServer on 127.0.0.1 only, serving
the page (``static/``), plotly.js from the installed ``plotly`` package (no network needed), the
data (``/data.json``) and its version (``/version``: the page polls it twice a second and fetches
the data when it changed, which a followed mission does at each recorder flush).
"""

from __future__ import annotations

import importlib.util
import json
import os
import sys
import threading
import time
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any, Callable

from ..errors import CikanError

STATIC = Path(__file__).with_name("static")
#: Files of the page: URL path -> (file name, content type).
PAGE = {"/": ("index.html", "text/html; charset=utf-8"), "/view.js": ("view.js", "text/javascript"),
        "/view.css": ("view.css", "text/css")}
#: The only address the view listens on: this machine.
HOST = "127.0.0.1"
#: Seconds between two reads of a followed bag.
FOLLOW_PERIOD_S = 0.5


def plotly_js() -> Path:
    """plotly.min.js as shipped inside the ``plotly`` package (the ``view`` extra); CikanError
    if it is not installed."""
    spec = importlib.util.find_spec("plotly")
    path = Path(spec.origin).parent / "package_data" / "plotly.min.js" if spec and spec.origin else None
    if path is None or not path.is_file():
        raise CikanError("plotly.js not found: the view needs the plotly package (the project's 'view' "
                         "extra: make install)")
    return path


class ViewData:
    """The data the page shows and its version (thread-safe: the follower sets, the server reads)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.version = 0
        self.body = b"null"
        self.complete = False

    def set(self, body: bytes, complete: bool) -> None:
        with self._lock:
            self.body, self.complete = body, complete
            self.version += 1

    def get(self) -> tuple[int, bytes, bool]:
        with self._lock:
            return self.version, self.body, self.complete


def handler(view: ViewData, script: Path) -> type[BaseHTTPRequestHandler]:
    """The request handler of a view: the page, plotly.js, ``/data.json`` and ``/version``."""

    class Handler(BaseHTTPRequestHandler):
        def do_GET(self) -> None:   # noqa: N802 (http.server's name)
            path = self.path.split("?", 1)[0]
            if path in PAGE:
                name, kind = PAGE[path]
                self.send(STATIC.joinpath(name).read_bytes(), kind)
            elif path == "/plotly.min.js":
                self.send(script.read_bytes(), "text/javascript", cache=True)
            elif path == "/data.json":
                version, body, _ = view.get()
                self.send(body, "application/json", version=version)
            elif path == "/version":
                version, _, complete = view.get()
                self.send(json.dumps({"version": version, "complete": complete}).encode(), "application/json")
            else:
                self.send_error(HTTPStatus.NOT_FOUND)

        def send(self, body: bytes, kind: str, cache: bool = False, version: int | None = None) -> None:
            self.send_response(HTTPStatus.OK)
            self.send_header("Content-Type", kind)
            if version is not None:
                self.send_header("X-View-Version", str(version))
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "max-age=86400" if cache else "no-store")
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, format: str, *args: Any) -> None:   # quiet: the terminal shows the URL only
            pass

    return Handler


def display_available() -> bool:
    """Can a browser window open here (a desktop session, macOS, Windows)? Without one,
    ``webbrowser`` would start a text browser in the terminal."""
    return sys.platform in ("darwin", "win32") or bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def serve(view: ViewData, port: int = 0, open_browser: bool = True,
          follow: Callable[[], bool] | None = None, announce: Callable[[str], None] | None = None) -> None:
    """Serve ``view`` on http://127.0.0.1:PORT/ (``port`` 0: a free one) until Ctrl-C; print the
    URL first (``announce``). ``follow()``, if given, is called every :data:`FOLLOW_PERIOD_S`
    in a thread until it returns False (the followed mission ended)."""
    script = plotly_js()
    try:
        server = ThreadingHTTPServer((HOST, port), handler(view, script))
    except OSError as exc:
        raise CikanError(f"cannot listen on {HOST}:{port}: {exc.strerror or exc}") from None
    server.daemon_threads = True
    url = f"http://{HOST}:{server.server_address[1]}/"
    (announce or print)(url)
    if follow is not None:
        def loop() -> None:
            while follow():
                time.sleep(FOLLOW_PERIOD_S)
        threading.Thread(target=loop, name="follow", daemon=True).start()
    if open_browser and display_available():
        import webbrowser

        webbrowser.open(url)
    try:
        server.serve_forever(poll_interval=0.2)
    finally:
        server.server_close()
