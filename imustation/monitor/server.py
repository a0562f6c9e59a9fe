"""The monitor's web server (tornado): one page, its vendored static files, three JSON endpoints.

Security model (docs/monitor.md):

* GET and HEAD only; every other method gets 405. No endpoint changes anything.
* Bound to 127.0.0.1 unless ``--host`` says otherwise. On a loopback address,
  requests must name a loopback ``Host`` (defeats DNS rebinding). On any other
  address a random token (``secrets.token_urlsafe``) is required on every
  request: ``?token=...`` (the page then keeps it in a same-site, HttpOnly
  cookie) or the ``X-Imustation-Token`` header; otherwise 403.
* Static files come from the package's ``static/`` folder through a fixed
  whitelist of names; the run file's path is fixed at start and never taken
  from a request, so no other file can be served.
"""

from __future__ import annotations

import asyncio
import errno
import hmac
import ipaddress
import json
import math
import re
import secrets
import signal
import socket
from collections.abc import Callable
from importlib import resources
from typing import Any

import numpy as np
import tornado.httpserver
import tornado.netutil
import tornado.web
from tornado.log import access_log, app_log

from imustation.errors import ImustationError
from imustation.monitor.watcher import Monitor

#: files served under /static/ (name -> content type); nothing else is
STATIC_FILES = {
    "monitor.js": "text/javascript; charset=utf-8",
    "monitor.css": "text/css; charset=utf-8",
    "uPlot.iife.min.js": "text/javascript; charset=utf-8",
    "uPlot.min.css": "text/css; charset=utf-8",
    "uPlot.LICENSE": "text/plain; charset=utf-8",
}
INDEX = "index.html"
TOKEN_COOKIE = "imustation_token"
TOKEN_HEADER = "X-Imustation-Token"


def is_loopback(host: str) -> bool:
    """True for localhost and loopback addresses (127.0.0.0/8, ::1)."""
    h = host.strip("[]")
    if h == "localhost":
        return True
    try:
        return ipaddress.ip_address(h).is_loopback
    except ValueError:
        return False


def _static_bytes(name: str) -> bytes:
    return resources.files("imustation.monitor").joinpath("static", name).read_bytes()


def jsonable(obj: Any) -> Any:
    """numpy arrays and scalars to lists and numbers; NaN and infinities to null."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        v = float(obj)
        return v if math.isfinite(v) else None
    if isinstance(obj, bytes):
        return obj.decode(errors="replace")
    return obj


class _Base(tornado.web.RequestHandler):
    SUPPORTED_METHODS = ("GET", "HEAD")

    def initialize(self, monitor: Monitor, token: str | None, loopback: bool) -> None:
        self.monitor = monitor
        self.token = token
        self.loopback = loopback

    def set_default_headers(self) -> None:
        self.set_header("X-Content-Type-Options", "nosniff")
        self.set_header("X-Frame-Options", "DENY")
        self.set_header("Referrer-Policy", "no-referrer")
        self.set_header(
            "Content-Security-Policy",
            "default-src 'self'; img-src 'self' data:; style-src 'self'; script-src 'self'; "
            "connect-src 'self'; frame-ancestors 'none'; form-action 'none'; base-uri 'none'",
        )

    def prepare(self) -> None:
        if self.loopback:
            host = self.request.host_name or ""
            if not is_loopback(host):
                raise tornado.web.HTTPError(403, reason="Forbidden host")
        if self.token is not None:
            given = (
                self.get_query_argument("token", None)
                or self.request.headers.get(TOKEN_HEADER)
                or self.get_cookie(TOKEN_COOKIE)
            )
            if not given or not hmac.compare_digest(given.encode(), self.token.encode()):
                raise tornado.web.HTTPError(403, reason="Token required")

    def log_exception(self, typ, value, tb) -> None:
        """Tornado's default prints the whole request (URI with the token, the token cookie)."""
        if isinstance(value, tornado.web.HTTPError):
            return  # the access log has the line
        app_log.error("uncaught exception in %s %s", self.request.method, redact(self.request.uri or ""),
                      exc_info=(typ, value, tb))  # fmt: skip

    def write_error(self, status_code: int, **kwargs: Any) -> None:
        self.set_header("Content-Type", "text/plain; charset=utf-8")
        self.finish(f"{status_code} {self._reason}\n")

    def head(self, *args: str) -> None:
        self.get(*args)


class IndexHandler(_Base):
    def get(self) -> None:
        if self.token is not None and self.get_query_argument("token", None):
            self.set_cookie(TOKEN_COOKIE, self.token, httponly=True, samesite="Strict")
        self.set_header("Content-Type", "text/html; charset=utf-8")
        self.set_header("Cache-Control", "no-store")
        self.write(self.application.settings["index_html"])


class StaticHandler(_Base):
    def get(self, name: str) -> None:
        if name not in STATIC_FILES:
            raise tornado.web.HTTPError(404)
        self.set_header("Content-Type", STATIC_FILES[name])
        self.set_header("Cache-Control", "max-age=3600")
        self.write(self.application.settings["static_cache"][name])


class _Json(_Base):
    def send(self, doc: dict[str, Any]) -> None:
        self.set_header("Content-Type", "application/json")
        self.set_header("Cache-Control", "no-store")
        self.write(json.dumps(jsonable(doc), allow_nan=False))


class StatusHandler(_Json):
    def get(self) -> None:
        self.send(self.monitor.status())


class TemperaturesHandler(_Json):
    def get(self) -> None:
        try:
            points = int(self.get_query_argument("max_points", "1500"))
        except ValueError:
            raise tornado.web.HTTPError(400, reason="max_points must be an integer") from None
        self.send(self.monitor.temperatures(max(10, min(points, 20000))))


class AllanHandler(_Json):
    def get(self) -> None:
        self.send(self.monitor.allan())


class NotFound(_Base):
    def prepare(self) -> None:
        super().prepare()
        raise tornado.web.HTTPError(404)


_TOKEN_IN_QUERY = re.compile(r"(?<=[?&]token=)[^&#]*")


def redact(uri: str) -> str:
    """``uri`` with the value of its ``token`` query parameter replaced, for logs."""
    return _TOKEN_IN_QUERY.sub("REDACTED", uri)


def log_request(handler: tornado.web.RequestHandler) -> None:
    """Tornado's access log line, without the token a request may carry in its URL.

    (Tornado logs every 4xx/5xx request at warning/error level with its full URI,
    and the default logging setup prints those on stderr.)
    """
    status = handler.get_status()
    log = access_log.info if status < 400 else access_log.warning if status < 500 else access_log.error
    req = handler.request
    log("%d %s %s (%s) %.2fms", status, req.method, redact(req.uri or ""), req.remote_ip, 1000 * req.request_time())


def make_app(monitor: Monitor, *, token: str | None, loopback: bool) -> tornado.web.Application:
    """The tornado application: routes, whitelisted static files read once from the package."""
    args = {"monitor": monitor, "token": token, "loopback": loopback}
    return tornado.web.Application(
        [
            (r"/", IndexHandler, args),
            (r"/static/([A-Za-z0-9._-]+)", StaticHandler, args),
            (r"/api/status", StatusHandler, args),
            (r"/api/temperatures", TemperaturesHandler, args),
            (r"/api/allan", AllanHandler, args),
        ],
        default_handler_class=NotFound,
        default_handler_args=args,
        index_html=_static_bytes(INDEX),
        static_cache={name: _static_bytes(name) for name in STATIC_FILES},
        compress_response=True,
        log_function=log_request,
        xsrf_cookies=False,  # nothing accepts a write
    )


def bind(host: str, port: int) -> list[socket.socket]:
    """Listening sockets on ``host:port`` (port 0: any free port); one-line error when taken."""
    try:
        return tornado.netutil.bind_sockets(port, address=host)
    except OSError as exc:
        if exc.errno == errno.EADDRINUSE:
            raise ImustationError(f"port {port} on {host} is in use; choose another with --port") from None
        if isinstance(exc, socket.gaierror) or exc.errno in (errno.EADDRNOTAVAIL,):
            raise ImustationError(f"--host {host}: not an address of this machine") from None
        raise ImustationError(f"cannot listen on {host}:{port}: {exc.strerror or exc}") from None


def new_token(host: str) -> str | None:
    """A random token when ``host`` is not a loopback address, else None."""
    return None if is_loopback(host) else secrets.token_urlsafe(24)


def serve(
    monitor: Monitor,
    sockets: list[socket.socket],
    *,
    token: str | None,
    loopback: bool,
    ready: Callable[[], None] | None = None,
) -> None:
    """Run the server on ``sockets`` until SIGINT/SIGTERM; starts and stops the monitor's threads."""

    async def main() -> None:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            try:
                loop.add_signal_handler(sig, stop.set)
            except (NotImplementedError, RuntimeError, ValueError):
                pass
        server = tornado.httpserver.HTTPServer(make_app(monitor, token=token, loopback=loopback))
        server.add_sockets(sockets)
        monitor.start()
        if ready is not None:
            ready()
        try:
            await stop.wait()
        finally:
            server.stop()
            monitor.stop()

    asyncio.run(main())
