"""Who may open the page and its websocket: the same origin always, a token beyond loopback.

viser serves the page and the websocket on one port through the ``websockets`` library, whose
``serve(..., process_request=...)`` hook sees every HTTP request (the page's ``GET /`` and the
websocket's upgrade) before it is answered. viser passes its own hook (the page's files) and
offers no other; :func:`guarded_server` wraps it: while it builds the :class:`viser.ViserServer`,
``websockets.asyncio.server.serve`` is replaced (under a lock, and restored at once) by a
function that puts :class:`AccessGate` in front of viser's hook. If viser no longer serves
through that function (another viser version), the server is stopped and
:class:`AccessGateError` is raised: a server that cannot be guarded is never left running.
viser 1.0 to 1.1 serve this way (``pyproject.toml`` pins the range; the tests check the gate
is in place).

The gate answers ``403 Forbidden`` (a short text, nothing else) to a request

- whose ``Origin`` header (browsers send it with every websocket) is not the origin the request
  was sent to (``http://`` + its ``Host``): a page of another site, or of another port of this
  host, cannot open the websocket and drive the controls;
- whose ``Host`` is not a loopback name while the server needs no token (``localhost``,
  ``127.0.0.1``, ``[::1]``): a page of another site whose name was made to point at this machine
  (DNS rebinding) is then refused too;
- without the token, when the server has one (:class:`AccessPolicy`): the page's URL carries it
  (``/?token=...``, as Jupyter's); the page's response sets it as a cookie
  (``HttpOnly; SameSite=Strict``, named after the port), so that the websocket the page opens
  carries it too.

Every page also gets ``X-Frame-Options: DENY`` (no other site can frame it and trick clicks)
and ``Referrer-Policy: no-referrer`` (its URL, and so the token, is never sent elsewhere).
"""

from __future__ import annotations

import contextlib
import hmac
import http
import io
import ipaddress
import os
import secrets
import sys
import threading
import urllib.parse
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from cogmap_core.errors import CogmapError

if TYPE_CHECKING:
    import viser

#: Hosts that mean "this machine only".
LOOPBACK_NAMES = frozenset({"localhost", "localhost.", "ip6-localhost"})
#: The environment variable that fixes the token (e.g. for a container); at least 16 characters.
TOKEN_ENV = "COGMAP_TOKEN"
MIN_TOKEN_LENGTH = 16

_PATCH_LOCK = threading.Lock()

ProcessRequest = Callable[[Any, Any], Any]


class AccessGateError(CogmapError):
    """The server could not be guarded (viser serves its page another way)."""


def is_loopback(host: str) -> bool:
    """Whether ``host`` (a name or an address, IPv6 with or without brackets) is this machine."""
    name = host.strip().lower().removeprefix("[").removesuffix("]")
    if name in LOOPBACK_NAMES:
        return True
    try:
        return ipaddress.ip_address(name).is_loopback
    except ValueError:
        return False


def new_token(environ: Mapping[str, str] | None = None) -> str:
    """The token: ``$COGMAP_TOKEN`` when set (checked), else a new random one (32 characters).

    Raises:
        CogmapError: ``$COGMAP_TOKEN`` is shorter than :data:`MIN_TOKEN_LENGTH` or holds
            characters a URL would have to escape.

    """
    fixed = (environ if environ is not None else os.environ).get(TOKEN_ENV)
    if fixed is None or fixed == "":
        return secrets.token_urlsafe(24)
    if len(fixed) < MIN_TOKEN_LENGTH or urllib.parse.quote(fixed, safe="-_.~") != fixed:
        raise CogmapError(
            f"{TOKEN_ENV} must be at least {MIN_TOKEN_LENGTH} characters of A-Z, a-z, 0-9, "
            "'-', '_', '.', '~'; unset it to have a random token made"
        )
    return fixed


@dataclass
class AccessPolicy:
    """What the gate asks of a request.

    Attributes:
        token: the token a request must carry (None: none needed).
        loopback_only: refuse requests whose ``Host`` is not a loopback name (a server bound
            to loopback that needs no token).
        port: the port served (names the token's cookie; set once the server is bound).

    """

    token: str | None = None
    loopback_only: bool = True
    port: int = 0

    @property
    def cookie(self) -> str:
        """The name of the token's cookie (cookies do not tell ports apart: the name does)."""
        return f"cogmap-token-{self.port}"


def policy_for(host: str, require_token: bool = False, no_token: bool = False) -> AccessPolicy:
    """The policy of a server bound to ``host``: a token unless on loopback (or ``no_token``)."""
    loopback = is_loopback(host)
    needs_token = (require_token or not loopback) and not no_token
    return AccessPolicy(token=new_token() if needs_token else None, loopback_only=loopback)


class AccessGate:
    """The ``process_request`` hook in front of viser's (module doc)."""

    def __init__(self, policy: AccessPolicy) -> None:
        """Guard requests with ``policy``."""
        self.policy = policy
        self.installed = False  # set when a websockets server was built with the gate
        self.refused = 0

    def wrap(self, inner: ProcessRequest | None) -> ProcessRequest:
        """The hook to give ``serve``: the gate, then ``inner`` (viser's page server)."""

        def process_request(connection: Any, request: Any) -> Any:
            reason = self.refusal(request.headers, request.path)
            if reason is not None:
                self.refused += 1
                return connection.respond(http.HTTPStatus.FORBIDDEN, f"cogmap: {reason}\n")
            response = inner(connection, request) if inner is not None else None
            if response is not None:
                self._decorate(response.headers, request.path)
            return response

        self.installed = True
        return process_request

    # ------------------------------------------------------------------ the checks
    def refusal(self, headers: Any, path: str) -> str | None:
        """Why a request with these headers for ``path`` is refused (None: it is not)."""
        hosts = _all(headers, "Host")
        if len(hosts) != 1 or not hosts[0]:
            return "a request needs exactly one Host header"
        host = hosts[0]
        hostname = _hostname(host)
        if self.policy.loopback_only and not is_loopback(hostname):
            return (
                "this server answers only requests addressed to this machine (localhost, "
                "127.0.0.1, [::1])"
            )
        origins = _all(headers, "Origin")
        if len(origins) > 1 or (origins and not _same_origin(origins[0], host)):
            return "a page of another origin may not connect to this server"
        token = self.policy.token
        if token is not None and not self._has_token(headers, path, token):
            return (
                "this server needs its token: open the URL that cogmap serve printed (it ends "
                "in ?token=...)"
            )
        return None

    def _has_token(self, headers: Any, path: str, token: str) -> bool:
        given = _query_token(path)
        if given is None:
            given = _cookie(headers, self.policy.cookie)
        return given is not None and hmac.compare_digest(given.encode(), token.encode())

    def _decorate(self, headers: Any, path: str) -> None:
        """Headers of every page response; the token's cookie when the URL carried it."""
        headers["X-Frame-Options"] = "DENY"
        headers["Content-Security-Policy"] = "frame-ancestors 'none'"
        headers["Referrer-Policy"] = "no-referrer"
        token = self.policy.token
        if token is not None and _query_token(path) is not None:
            headers["Set-Cookie"] = (
                f"{self.policy.cookie}={token}; Path=/; HttpOnly; SameSite=Strict"
            )


def _all(headers: Any, name: str) -> list[str]:
    return list(headers.get_all(name)) if hasattr(headers, "get_all") else []


def _hostname(host: str) -> str:
    """The name in a ``Host`` header (without its port; IPv6 without brackets)."""
    host = host.strip()
    if host.startswith("["):
        return host[1 : host.find("]")] if "]" in host else host
    return host.rsplit(":", 1)[0] if host.count(":") == 1 else host


def _same_origin(origin: str, host: str) -> bool:
    parsed = urllib.parse.urlsplit(origin.strip())
    if parsed.scheme not in ("http", "https") or not parsed.netloc:
        return False  # "null" (a sandboxed frame, a file), or anything else
    return parsed.netloc.lower() == host.strip().lower()


def _query_token(path: str) -> str | None:
    query = urllib.parse.urlsplit(path).query
    values = urllib.parse.parse_qs(query).get("token")
    return values[-1] if values else None


def _cookie(headers: Any, name: str) -> str | None:
    for line in _all(headers, "Cookie"):
        for part in line.split(";"):
            key, _, value = part.strip().partition("=")
            if key == name:
                return value
    return None


# ---------------------------------------------------------------------------------- the server
@contextlib.contextmanager
def _gate_websockets_serve(gate: AccessGate) -> Iterator[None]:
    """While the block runs, websockets servers are built with ``gate`` in front of their hook."""
    import websockets.asyncio.server as ws_server

    original = ws_server.serve

    def serve(*args: Any, **kwargs: Any) -> Any:
        kwargs["process_request"] = gate.wrap(kwargs.get("process_request"))
        return original(*args, **kwargs)

    with _PATCH_LOCK:
        ws_server.serve = serve  # type: ignore[misc,assignment]
        try:
            yield
        finally:
            ws_server.serve = original  # type: ignore[misc]


def guarded_server(
    host: str,
    port: int,
    policy: AccessPolicy,
    label: str | None = "cogmap",
    verbose: bool = False,
    quiet: bool = False,
) -> viser.ViserServer:
    """A viser server on ``host``:``port`` whose every request passes :class:`AccessGate`.

    ``quiet`` silences viser's banner (else it goes to stderr, keeping stdout for our URL).

    Raises:
        AccessGateError: viser built its server without the hook (it changed how it serves).

    """
    import viser

    gate = AccessGate(policy)
    sink: Any = io.StringIO() if quiet else sys.stderr
    with _gate_websockets_serve(gate), contextlib.redirect_stdout(sink):
        server = viser.ViserServer(host=host, port=port, label=label, verbose=verbose)
    if not gate.installed:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            server.stop()
        raise AccessGateError(
            f"viser {viser.__version__} does not serve its page through the hook cogmap guards; "
            "install a viser version this cogmap supports (see pyproject.toml)"
        )
    policy.port = server.get_port()
    server.access_gate = gate  # type: ignore[attr-defined]  # (tests and benchmarks)
    return server


def page_url(host: str, port: int, token: str | None) -> str:
    """The URL to open: ``http://HOST:PORT`` (``/?token=...`` when the server has a token).

    A server on every interface (``0.0.0.0``, ``::``) is named by this machine's host name.
    """
    if host in ("0.0.0.0", "::", ""):
        import socket

        host = socket.gethostname() or "localhost"
    if ":" in host:
        host = f"[{host}]"
    base = f"http://{host}:{port}"
    return f"{base}/?token={token}" if token is not None else base
