"""The preview's web server: its page, the renders, the status and the
page's requests, for whoever has the URL's token.

A local server that reads the user's files is a boundary, kept so:

- it listens on 127.0.0.1 unless told otherwise;
- every request carries the URL's random token, or is refused (403);
- the answers are a fixed set of routes, the page's files read from the
  package once, at the start: no part of a request names a file;
- a request whose Host header is a name other than the server's own (an
  address, ``localhost``, the name given to ``--host``) is refused, so that
  a web site whose name is made to point at 127.0.0.1 (DNS rebinding) reads
  nothing from it.
"""

from __future__ import annotations

import errno
import hmac
import ipaddress
import json
import secrets
import socket
import warnings
import webbrowser
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from pathlib import Path
from string import Template
from urllib.parse import parse_qs, urlsplit

from ..errors import Error, UsageError, one_sentence
from .session import Session
from .watcher import Watcher

#: Seconds between the comments that keep an idle event stream open.
KEEP_ALIVE = 15
#: The largest request body taken (the page sends a few numbers).
LARGEST_BODY = 4096
#: Hosts that make the server reachable from other machines.
WILDCARDS = ("0.0.0.0", "::")


def serve(path: Path, defines: dict, host: str, port: int, open_browser: bool) -> int:
    """Serve the preview of the scene at ``path`` until Ctrl-C; the URL is
    the first line of stdout."""
    server = _listen(host, port)
    watcher = Watcher(lambda: session.files_changed())
    session = Session(path, defines, watcher.watch)
    session.start()
    server.session, server.token = session, secrets.token_urlsafe(24)
    server.names = _own_names(host)
    server.page = _page_files(server.token)
    url = f"http://{_url_host(host)}:{server.server_address[1]}/?token={server.token}"
    print(url, flush=True)
    if host in WILDCARDS:
        warnings.warn(f"--host {host} serves the preview on every network interface: anyone "
                      "who can reach this machine and has the URL sees the scene and can save "
                      "images into the working folder.")
    if open_browser:
        webbrowser.open(url)
    server.serve_forever()
    return 0


class _Server(ThreadingHTTPServer):
    daemon_threads = True


def _listen(host: str, port: int) -> _Server:
    """The server, bound to ``host:port``, or a :class:`UsageError`."""
    _Server.address_family = socket.AF_INET6 if ":" in host else socket.AF_INET
    try:
        return _Server((host, port), _Handler)
    except socket.gaierror:
        raise UsageError(f"cannot listen on '{host}': it is not an address or a known "
                         "host name.") from None
    except OSError as error:
        why = ("the port is in use; choose another --port, or leave it out for a free one"
               if error.errno == errno.EADDRINUSE else error.strerror)
        raise UsageError(f"cannot listen on {host}:{port}: {why}.") from None


def _url_host(host: str) -> str:
    if host in WILDCARDS:
        return socket.gethostname()
    return f"[{host}]" if ":" in host else host


def _own_names(host: str) -> set[str]:
    """The host names a request may give (addresses are always taken)."""
    names = {"localhost", host.lower()}
    if host in WILDCARDS:
        names |= {socket.gethostname().lower(), socket.getfqdn().lower()}
    return names


def _page_files(token: str) -> dict[str, tuple[str, bytes]]:
    """The page's files by route: content type and bytes, the token put
    into the page's links."""
    folder = resources.files(__package__)
    html = Template(folder.joinpath("page.html").read_text()).substitute(token=token)
    return {"/": ("text/html; charset=utf-8", html.encode()),
            "/page.js": ("text/javascript; charset=utf-8", folder.joinpath("page.js").read_bytes()),
            "/page.css": ("text/css; charset=utf-8", folder.joinpath("page.css").read_bytes())}


def _is_address(name: str) -> bool:
    try:
        ipaddress.ip_address(name.strip("[]"))
    except ValueError:
        return False
    return True


class _Handler(BaseHTTPRequestHandler):
    server_version = "mitsuba-whitted-preview"
    protocol_version = "HTTP/1.1"

    def log_message(self, format, *args):
        pass  # the terminal shows the URL and what fails, not each request

    def do_GET(self):
        self._answer(_GET)

    def do_POST(self):
        self._answer(_POST)

    def _answer(self, routes: dict) -> None:
        url = urlsplit(self.path)
        query = parse_qs(url.query)
        if not self._host_allowed():
            return self._send_text(HTTPStatus.FORBIDDEN, "unknown Host header")
        given = query.get("token", [""])[0]
        if not hmac.compare_digest(given.encode(), self.server.token.encode()):
            return self._send_text(HTTPStatus.FORBIDDEN, "the URL's token is missing or wrong")
        route = routes.get(url.path)
        if route is None:
            return self._send_text(HTTPStatus.NOT_FOUND, "no such page")
        route(self)

    def _host_allowed(self) -> bool:
        name, _, port = (self.headers.get("Host") or "").rpartition(":")
        return port == str(self.server.server_address[1]) and (
            name.lower() in self.server.names or _is_address(name))

    # ----------------------------------------------------------------- answers

    def _send(self, status: int, kind: str, body: bytes, headers: dict | None = None) -> None:
        self.send_response(status)
        self.send_header("Content-Type", kind)
        for name, value in (headers or {}).items():
            self.send_header(name, value)
        self.send_header("Content-Length", str(len(body)))
        self._common_headers()
        self.end_headers()
        self.wfile.write(body)

    def _common_headers(self) -> None:
        self.send_header("Cache-Control", "no-store")
        self.send_header("X-Content-Type-Options", "nosniff")
        self.send_header("Referrer-Policy", "no-referrer")
        self.send_header("Content-Security-Policy", "default-src 'self'; frame-ancestors 'none'")

    def _send_text(self, status: int, text: str) -> None:
        self._send(status, "text/plain; charset=utf-8", (text + "\n").encode())

    def _send_json(self, value, status: int = HTTPStatus.OK) -> None:
        self._send(status, "application/json", json.dumps(value).encode())

    def _body(self) -> dict:
        length = int(self.headers.get("Content-Length") or 0)
        if not 0 <= length <= LARGEST_BODY:
            raise ValueError("the request is too large.")
        value = json.loads(self.rfile.read(length) or b"{}")
        if not isinstance(value, dict):
            raise ValueError("the request must be a JSON object.")
        return value

    def _page_file(self) -> None:
        self._send(HTTPStatus.OK, *self.server.page[urlsplit(self.path).path])

    def _image(self) -> None:
        png, generation = self.server.session.shown()
        # The status's generation of this image: a script that reads the
        # image after an event knows whether a newer one came between.
        self._send(HTTPStatus.OK, "image/png", png, {"X-Generation": str(generation)})

    def _status(self) -> None:
        self._send_json(self.server.session.status())

    def _events(self) -> None:
        """Server-sent events: the status each time it changes."""
        self.send_response(HTTPStatus.OK)
        self.send_header("Content-Type", "text/event-stream")
        self._common_headers()
        self.end_headers()
        self.close_connection = True
        seen = -1
        try:
            while True:
                status, seen = self.server.session.next_status(seen, KEEP_ALIVE)
                self.wfile.write(f"data: {json.dumps(status)}\n\n".encode() if status
                                 else b": still here\n\n")
                self.wfile.flush()
        except (BrokenPipeError, ConnectionResetError):
            pass  # the page was closed

    def _action(self, act) -> None:
        """``act(body)`` for a POST; its JSON answer, or its error's sentence."""
        try:
            self._send_json(act(self._body()) or {})
        except (Error, ValueError, TypeError, OSError) as error:
            self._send_json({"error": one_sentence(error)}, HTTPStatus.BAD_REQUEST)

    def _camera(self) -> None:
        self._action(lambda body: self.server.session.move_camera(
            str(body.get("move")), float(body.get("x", 0)), float(body.get("y", 0))))

    def _settings(self) -> None:
        self._action(self.server.session.change_settings)

    def _save(self) -> None:
        def save(body):
            path = self.server.session.save(Path.cwd())
            print(f"saved {path}", flush=True)
            return {"saved": str(path)}

        self._action(save)


_GET = {"/": _Handler._page_file, "/page.js": _Handler._page_file,
        "/page.css": _Handler._page_file, "/image.png": _Handler._image,
        "/status": _Handler._status, "/events": _Handler._events}
_POST = {"/camera": _Handler._camera, "/settings": _Handler._settings,
         "/save": _Handler._save}
