"""The local web server of ``fracture view``: static page, bake files and a small state API.

Routes (GET and HEAD only):

* ``/`` and ``/static/...``: the page (``static/``), with three.js and the
  JavaScript runtime reader in ``static/vendor/`` (built by ``make web``);
* ``/api/state``: the assets of the folder, each with a version key the page
  polls to reload after a re-bake (:func:`fracture_cli.view.assets.list_assets`);
* ``/files/<name>``: one bake output file (``.glb``, ``.fracture.json``,
  ``.fracture.bin``, ``.report.json``, ``.aligned.json``, ``.aligned.bin``) of the folder, nothing else.

The server binds to the loopback interface unless told otherwise; it only
reads files. Two checks keep those files local:

* the ``Host`` header must name this server (:func:`host_allowed`): a page on
  another site whose name an attacker re-points at 127.0.0.1 (DNS rebinding)
  sends its own name and gets 403, so it cannot read the served files;
* a file is served only if its real path (symbolic links resolved) is inside
  the folder served (``static/`` or the bake folder), and only if it is a
  regular file (a FIFO is never opened in a way that could block a thread).
"""

from __future__ import annotations

import http.server
import ipaddress
import json
import logging
import mimetypes
import os
import posixpath
import socket
import threading
import urllib.parse
from dataclasses import dataclass
from typing import Self

from fracture_cli.errors import FractureError, UsageError
from fracture_cli.io.inputs import NotRegularFile, read_regular
from fracture_cli.view.assets import ViewSource, list_assets, served_file

log = logging.getLogger(__name__)

STATIC_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "static")
VENDOR_DIR = os.path.join(STATIC_DIR, "vendor")
# What the page imports from vendor/; if any is missing the page cannot start.
VENDOR_FILES = ("three.module.js", "three.core.js", "addons/controls/OrbitControls.js",
                "addons/loaders/GLTFLoader.js", "fracture_runtime.js", "fracture_aligned.js")
POLL_MILLISECONDS = 1000
_TYPES = {".js": "text/javascript", ".mjs": "text/javascript", ".css": "text/css", ".html": "text/html",
          ".json": "application/json", ".glb": "model/gltf-binary", ".bin": "application/octet-stream",
          ".png": "image/png", ".svg": "image/svg+xml"}


@dataclass(frozen=True)
class ViewOptions:
    """How to serve.

    Attributes
    ----------
    host : str
        Interface to bind; the default is loopback only.
    port : int
        TCP port; 0 picks a free one.
    """

    host: str = "127.0.0.1"
    port: int = 8765


def check_vendor() -> None:
    """Raise a one-line error when the built web assets (three.js, the reader) are missing."""
    missing = [name for name in VENDOR_FILES if not os.path.isfile(os.path.join(VENDOR_DIR, name))]
    if missing:
        raise FractureError(f"the viewer's web files are not built ({os.path.relpath(VENDOR_DIR)}/{missing[0]} "
                            "is missing); run 'make web' in the fracture source folder (needs npm)")


def is_loopback(host: str) -> bool:
    """Whether ``host`` names only this machine (127.0.0.0/8, ::1, localhost)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _split_host(header: str) -> tuple[str, int | None] | None:
    """(name, port or None) of a ``Host`` header value, or None if it is malformed."""
    header = header.strip()
    if header.startswith("["):  # [IPv6]:port
        name, sep, rest = header[1:].partition("]")
        if not sep or (rest and not rest.startswith(":")):
            return None
        port_text = rest[1:] if rest else None
    elif header.count(":") == 1:
        name, port_text = header.split(":")
    elif ":" in header:
        return None
    else:
        name, port_text = header, None
    if port_text is not None and not port_text.isdigit():
        return None
    return name.lower().rstrip("."), int(port_text) if port_text is not None else None


def _is_ip_literal(name: str) -> bool:
    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True


def host_allowed(header: str | None, bound_host: str, port: int) -> bool:
    """Whether a request's ``Host`` header names the server bound to ``bound_host:port``.

    A DNS-rebinding page reaches the server under its own domain name, so the
    rule is about names: an IP address literal (it cannot be re-pointed) that
    is loopback when the server is, ``localhost``, or, for a server bound to
    another interface, the machine's own host name or the name it was bound to.
    The port must be the server's (80 when the header has none).
    """
    if not header:
        return False
    split = _split_host(header)
    if split is None:
        return False
    name, given_port = split
    if (given_port if given_port is not None else 80) != port:
        return False
    if name == "localhost" or name == bound_host.lower():
        return True
    if _is_ip_literal(name):
        return is_loopback(name) or not is_loopback(bound_host)
    if is_loopback(bound_host):
        return False
    return name in {socket.gethostname().lower(), socket.getfqdn().lower()}


def _inside(path: str, folder: str) -> bool:
    """Whether ``path``'s real location (symbolic links resolved) is inside ``folder``'s."""
    real, root = os.path.realpath(path), os.path.realpath(folder)
    return os.path.commonpath([real, root]) == root


def _content_type(path: str) -> str:
    ext = os.path.splitext(path)[1].lower()
    return _TYPES.get(ext) or mimetypes.guess_type(path)[0] or "application/octet-stream"


def make_handler(source: ViewSource) -> type[http.server.BaseHTTPRequestHandler]:
    """A request handler class bound to one view source."""

    class Handler(http.server.BaseHTTPRequestHandler):
        server_version = "fracture-view"
        protocol_version = "HTTP/1.1"

        def log_message(self, format: str, *args) -> None:
            log.debug("view: %s %s", self.address_string(), format % args)

        def do_HEAD(self) -> None:
            self._route(send_body=False)

        def do_GET(self) -> None:
            self._route(send_body=True)

        def _route(self, send_body: bool) -> None:
            address = self.server.server_address
            bound, port = (address[0], address[1]) if isinstance(address, tuple) else (str(address), 0)
            if not host_allowed(self.headers.get("Host"), str(bound), int(port)):
                self._send_error(403, "the Host header does not name this server (refused: DNS rebinding "
                                      f"protection); open http://{_shown(str(bound))}:{port}/")
                return
            path = urllib.parse.urlsplit(self.path).path
            path = urllib.parse.unquote(path)
            if path in ("/", "/index.html"):
                self._send_file(os.path.join(STATIC_DIR, "index.html"), send_body)
            elif path.startswith("/static/"):
                self._send_file(_static_path(path[len("/static/"):]), send_body)
            elif path == "/api/state":
                try:
                    body = {"folder": source.folder, "single": source.stem, "poll_ms": POLL_MILLISECONDS,
                            "assets": list_assets(source)}
                except FractureError as exc:
                    body = {"folder": source.folder, "error": str(exc), "assets": [], "poll_ms": POLL_MILLISECONDS}
                self._send_bytes(json.dumps(body).encode(), "application/json", send_body)
            elif path.startswith("/files/"):
                self._send_file(served_file(source, path[len("/files/"):]), send_body)
            else:
                self._send_error(404, "not found")

        def _send_file(self, file_path: str | None, send_body: bool) -> None:
            if file_path is None or not os.path.isfile(file_path):
                self._send_error(404, "not found")
                return
            try:
                payload = read_regular(file_path)
            except NotRegularFile:
                self._send_error(404, "not found")
                return
            except OSError as exc:
                self._send_error(500, f"cannot read file ({exc.strerror})")
                return
            self._send_bytes(payload, _content_type(file_path), send_body)

        def _send_bytes(self, payload: bytes, content_type: str, send_body: bool, status: int = 200) -> None:
            self.send_response(status)
            self.send_header("Content-Type", content_type)
            self.send_header("Content-Length", str(len(payload)))
            # Bake files change under the page's feet; the page adds version keys to its URLs.
            self.send_header("Cache-Control", "no-store")
            self.send_header("X-Content-Type-Options", "nosniff")
            self.end_headers()
            if send_body:
                self.wfile.write(payload)

        def _send_error(self, status: int, message: str) -> None:
            self._send_bytes(message.encode() + b"\n", "text/plain; charset=utf-8", True, status)

    return Handler


def _static_path(relative: str) -> str | None:
    """Absolute path of a file under ``static/``, or None if the name escapes it."""
    clean = posixpath.normpath("/" + relative).lstrip("/")
    if not clean or clean.startswith("..") or "\0" in clean:
        return None
    path = os.path.join(STATIC_DIR, *clean.split("/"))
    return path if os.path.commonpath([path, STATIC_DIR]) == STATIC_DIR and _inside(path, STATIC_DIR) else None


def _shown(host: str) -> str:
    return f"[{host}]" if ":" in host else host


class ViewServer:
    """A running viewer: a threading HTTP server on its own thread.

    Use :meth:`start` (returns at once) and :meth:`stop`, or as a context manager.
    """

    def __init__(self, source: ViewSource, options: ViewOptions = ViewOptions()):
        check_vendor()
        self.source = source
        self.options = options
        family = socket.AF_INET6 if ":" in options.host else socket.AF_INET
        server_cls = type("Server", (http.server.ThreadingHTTPServer,), {"address_family": family,
                                                                          "daemon_threads": True})
        try:
            self.httpd = server_cls((options.host, options.port), make_handler(source))
        except OSError as exc:
            raise UsageError(f"cannot listen on {options.host}:{options.port} ({exc.strerror}); "
                             "pick another --port (0 picks a free one)") from None
        self._thread: threading.Thread | None = None

    @property
    def url(self) -> str:
        host, port = self.httpd.server_address[:2]
        return f"http://{_shown(str(host))}:{port}/"

    def start(self) -> Self:
        self._thread = threading.Thread(target=self.httpd.serve_forever, name="fracture-view", daemon=True)
        self._thread.start()
        return self

    def wait(self) -> None:
        """Block until the server stops (Ctrl-C raises KeyboardInterrupt here)."""
        while self._thread is not None and self._thread.is_alive():
            self._thread.join(0.5)

    def stop(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()
        if self._thread is not None:
            self._thread.join()
            self._thread = None

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()
