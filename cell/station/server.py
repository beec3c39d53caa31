"""The operator station: a local web page served by the cell (stdlib http.server, no dependency).

Routes (JSON unless said otherwise):

    GET  /                     the page (index.html, station.js, station.css: no CDN, works offline)
    GET  /api/state            {"session": this start's id, "control": RunControl.snapshot(),
                                "cell": backend.snapshot()}
    GET  /api/frame.png        the current camera frame (404 until there is one)
    POST /api/run | pause | step | approve | stop | reset
    POST /api/reject           {"reason": "..."}        (the loop turns it into an invalid example)
                               approve and reject may carry {"proposal": the one shown, "proposal_no": its
                               number}: 409 if another waits; a repeat of the decision on it is answered as done
    POST /api/approval         {"required": true|false}  (approve each grasp)
    POST /api/teach            {"part": id, "p1_px": [u, v], "p2_px": [u, v], "frame": index shown}
                               -> backend.teach(...); 409 if that frame is no longer the current one

Every POST needs the session token in the `X-Cell-Token` header: a missing or wrong token
gets 403 and changes nothing. GETs need none (looking is harmless). Each start of the station is
a session with an id of its own, in the state as `session`: a POST whose `X-Cell-Session` header
names another one (a page left open across a restart) gets 409 and changes nothing, but Stop.
The server binds to 127.0.0.1 by default and then also refuses requests whose Host header is not
a loopback name (a web page elsewhere cannot reach the arm through DNS rebinding); the custom header
makes every POST a CORS-preflighted request, which the server never grants to other origins.
Status codes: 400 bad input, 403 token/host, 404, 405 a method the route does not take (with
Allow), 409 a command the state does not allow.
"""

from __future__ import annotations

import hmac
import json
import logging
import math
import secrets
import socket
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from typing import Protocol
from urllib.parse import urlsplit

from cell.errors import BadInput
from cell.fileio import parse_json
from cell.runtime.control import DONE, STOPPED, InvalidCommand, RunControl

log = logging.getLogger(__name__)

TOKEN_HEADER = "X-Cell-Token"
SESSION_HEADER = "X-Cell-Session"  # the session whose state the page showed (optional)
MAX_BODY_BYTES = 64 * 1024
LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "::1")
WILDCARD_HOSTS = {"0.0.0.0": "127.0.0.1", "::": "::1"}  # bound to every interface -> its loopback address
STATIC = {"/": ("index.html", "text/html; charset=utf-8"),
          "/index.html": ("index.html", "text/html; charset=utf-8"),
          "/station.js": ("station.js", "text/javascript; charset=utf-8"),
          "/station.css": ("station.css", "text/css; charset=utf-8")}
GET_ONLY = ("/api/state", "/api/frame.png", "/favicon.ico", *STATIC)
COMMANDS = ("run", "pause", "step", "approve", "reject", "stop", "reset", "approval", "teach")


class StationBackend(Protocol):
    """What the cell loop offers the station (the loop implements it; tests use cell.station.demo).

    snapshot() -> dict, JSON-able, in image px (the image frame of CONTRACT.md):
        {"frame": {"index": int | None, "width_px": int, "height_px": int},
         "parts": [{"id": str, "outline_px": [[u, v], ...], "holes_px": [[[u, v], ...]]}],
         "proposal_px": None | {"target": id, "contacts_px": [[u, v], [u, v]],
                                "fingers_px": [[[u, v], ...], ...], "palm_px": [[u, v], ...]},
         "examples": {"path": str, "count": int[, "new_to": str]}, ...free keys shown as they are}
    frame_png() -> bytes | None: the current frame as PNG.
    teach(part_id, p1_px, p2_px) -> dict: make a valid example from two contact points in px
        (map to mm, snap to the outline, current configuration), append it atomically; the
        planner learns it (the cell loop: at its next plan); raise BadInput (400) or
        InvalidCommand (409) to refuse.
    stop() (optional): quick-stop the arm; called after RunControl.stop() on the page's Stop where that stopped
        a run (not one done or stopped already),
        so a motion under way ends at once rather than at the loop's next checkpoint.
    """

    def snapshot(self) -> dict: ...

    def frame_png(self) -> bytes | None: ...

    def teach(self, part_id: str, p1_px: list[float], p2_px: list[float]) -> dict: ...


MIN_TOKEN_CHARS = 8


class LengthRequired(BadInput):
    """A request body without a Content-Length (chunked): refused with 411."""


TOKEN_CHARS = frozenset("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789-._~")


def check_token(token: str | None) -> None:
    """Refuse a station token short enough to guess (None: a random one is made), or one the page cannot carry:
    it goes in the printed link's query and in an HTTP header, so letters, digits and - . _ ~ only ('abc&defgh'
    gave the page "abc", refused; '%zz' stopped its script; a non-ASCII one could not be sent)."""
    if token is not None and len(token) < MIN_TOKEN_CHARS:
        raise BadInput(f"the station token must be at least {MIN_TOKEN_CHARS} characters")
    if token is not None and not set(token) <= TOKEN_CHARS:
        odd = "".join(sorted(set(token) - TOKEN_CHARS))
        raise BadInput(f"the station token may hold letters, digits and - . _ ~ only (it goes in a link and an HTTP "
                       f"header), not {odd!r}")


def check_port_free(port: int, host: str = "127.0.0.1") -> None:
    """Refuse a port the station could not be served on, before anything that a refusal later would leave
    half made (`cell run --station --record DIR` left DIR as a recording of nothing). Bound and released as
    the station binds it (SO_REUSEADDR); 0 (any free port) always is."""
    if port == 0:
        return
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError as e:
            raise _cannot_serve(host, port, e) from None


def _cannot_serve(host: str, port: int, e: OSError) -> BadInput:
    return BadInput(f"cannot serve the station on {host}:{port}: {e.strerror or e}")


def new_token() -> str:
    return secrets.token_urlsafe(18)


def _point(raw, key: str) -> list[float]:
    if (not isinstance(raw, (list, tuple)) or len(raw) != 2
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                       for v in raw)):
        raise BadInput(f"'{key}' must be [u, v], two finite numbers (px)")
    return [float(raw[0]), float(raw[1])]


def _jsonable(obj):
    """`obj` with plain JSON values only. The loop's state holds numpy values (np.int64, np.bool_,
    np.float32, arrays: all have .tolist(), so numpy need not be imported here), which json.dumps
    refuses; NaN and infinity become null, since the page's JSON parser refuses the whole state
    for one of them."""
    if isinstance(obj, dict):
        return {k: _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if hasattr(obj, "tolist"):
        return _jsonable(obj.tolist())
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


class _Handler(BaseHTTPRequestHandler):
    server_version = "cell-station/1"
    station: StationServer  # set on the subclass made per server

    # -- plumbing
    def log_message(self, fmt, *args):  # route http.server's access log to logging, not stderr
        log.debug("%s " + fmt, self.address_string(), *args)

    def _send(self, status: int, body: bytes, ctype: str, extra: dict | None = None) -> None:
        self.send_response(status)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.send_header("X-Content-Type-Options", "nosniff")
        self.send_header("Content-Security-Policy",
                         "default-src 'self'; img-src 'self' data:; style-src 'self'; script-src 'self'")
        for k, v in (extra or {}).items():
            self.send_header(k, v)
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(body)

    def _json(self, status: int, obj) -> None:
        self._send(status, json.dumps(_jsonable(obj), separators=(",", ":")).encode("utf-8"), "application/json")

    def _error(self, status: int, message: str, **extra) -> None:
        self._json(status, {"ok": False, "error": message, **extra})

    def _not_allowed(self, allow: str) -> None:
        self._send(405, json.dumps({"ok": False, "error": f"{self.command} is not allowed here: use {allow}"}
                                   ).encode("utf-8"), "application/json", {"Allow": allow})

    def _allowed_methods(self, path: str) -> str:
        return "POST" if path.startswith("/api/") and path[len("/api/"):] in COMMANDS else "GET, HEAD"

    def _other_method(self):
        """PUT, DELETE, PATCH, OPTIONS (a CORS preflight: never granted), ...: 405, nothing done."""
        if not self._host_ok():
            return self._error(403, "this station only answers requests for 127.0.0.1 / localhost")
        return self._not_allowed(self._allowed_methods(urlsplit(self.path).path))

    do_PUT = do_DELETE = do_PATCH = do_OPTIONS = do_TRACE = do_CONNECT = _other_method

    def _host_ok(self) -> bool:
        if not self.station.loopback_only:
            return True
        host = self.headers.get("Host", "")
        try:
            name = urlsplit(f"//{host}").hostname or ""
        except ValueError:
            return False
        return name in LOOPBACK_HOSTS

    # -- GET
    def do_GET(self):  # noqa: N802 - http.server's naming
        if not self._host_ok():
            return self._error(403, "this station only answers requests for 127.0.0.1 / localhost")
        path = urlsplit(self.path).path
        st = self.station
        try:
            if path in STATIC:
                name, ctype = STATIC[path]
                return self._send(200, st.static_file(name), ctype)
            if path == "/api/state":
                return self._json(200, st.state())
            if path == "/api/frame.png":
                png = st.backend.frame_png()
                if png is None:
                    return self._error(404, "no frame yet")
                return self._send(200, png, "image/png")
            if path == "/favicon.ico":
                return self._send(204, b"", "image/x-icon")
            if self._allowed_methods(path) == "POST":
                return self._not_allowed("POST")
        except Exception as e:  # the loop's backend failed: say so, keep serving
            log.exception("GET %s failed", path)
            return self._error(500, f"{type(e).__name__}: {e}")
        return self._error(404, f"no such page: {path}")

    do_HEAD = do_GET

    # -- POST
    def do_POST(self):  # noqa: N802
        if not self._host_ok():
            return self._error(403, "this station only answers requests for 127.0.0.1 / localhost")
        st = self.station
        given = self.headers.get(TOKEN_HEADER, "")
        if not given or not hmac.compare_digest(given.encode(), st.token.encode()):
            self._drop_body()
            # the session tells the page whether the station restarted since it got its token
            return self._error(403, f"a valid token is required in the {TOKEN_HEADER} header "
                                    "(it is printed when the station starts)", session=st.session_id)
        path = urlsplit(self.path).path
        if path in GET_ONLY:
            self._drop_body()
            return self._not_allowed("GET, HEAD")
        if not path.startswith("/api/"):
            return self._error(404, f"no such command: {path}")
        cmd = path[len("/api/"):]
        if self._for_an_older_session(cmd):
            self._drop_body()
            return self._error(409, "the station was restarted since this page showed its state: nothing was "
                                    "done; the page shows the new state now, press again if still meant",
                               session=st.session_id)
        try:
            body = self._read_body()
            result = st.command(cmd, body)
        except InvalidCommand as e:
            return self._error(409, str(e))
        except LengthRequired as e:
            self.close_connection = True  # the chunks are still in the stream
            return self._error(411, str(e))
        except BadInput as e:
            return self._error(400, str(e))
        except KeyError as e:
            return self._error(404, str(e.args[0]) if e.args else "unknown command")
        except Exception as e:
            log.exception("POST %s failed", path)
            return self._error(500, f"{type(e).__name__}: {e}")
        try:
            state = st.state()
        except Exception as e:  # the command was done (a Stop applied): say so, not a dropped connection
            log.exception("the state after POST %s failed", path)
            return self._json(200, {"ok": True, "result": result, "session": st.session_id,
                                    "state_error": f"the cell cannot report its state ({type(e).__name__}: {e})"})
        return self._json(200, {"ok": True, "result": result, **state})

    def _for_an_older_session(self, cmd: str) -> bool:
        """A command from a page that showed an earlier start of the station (with a fixed --token it
        would pass): meant for what that page showed, not for this session. Stop is always meant."""
        shown = self.headers.get(SESSION_HEADER)
        return cmd != "stop" and shown is not None and shown != self.station.session_id

    def _drop_body(self) -> None:
        """Read and drop the body of a request that is refused, so the connection stays sane."""
        try:
            self._read_body(ignore=True)
        except BadInput:  # a body too large, of a bad length or chunked is left unread: the refusal is the same,
            self.close_connection = True  # and what is left of it in the stream is no next request

    def _read_body(self, ignore: bool = False) -> dict:
        if "chunked" in self.headers.get("Transfer-Encoding", "").lower():
            # not read (http.server does not decode it): a chunked Reject's reason was dropped and the default
            # one recorded; refused instead, as 411 says
            raise LengthRequired("a chunked body is not taken: send it with a Content-Length")
        try:
            n = int(self.headers.get("Content-Length") or 0)
        except ValueError:
            n = -1
        if n < 0:
            raise BadInput("Content-Length must be a number of bytes (0 or more)")
        if n > MAX_BODY_BYTES:
            raise BadInput(f"request body too large ({n} bytes, at most {MAX_BODY_BYTES})")
        raw = self.rfile.read(n) if n > 0 else b""
        if ignore or not raw.strip():
            return {}
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError:
            raise BadInput("request body must be a JSON object (UTF-8)") from None
        # as files are read: a key given twice (which did the operator mean?), half a UTF-16 pair (a reason
        # holding one reached the recording, which then refused to be read) ...
        body = parse_json(text, "request body")
        if not isinstance(body, dict):
            raise BadInput("request body must be a JSON object")
        return body


class _Server(ThreadingHTTPServer):
    request_queue_size = 64  # (socketserver's 5: of 64 requests at once, 44 were reset; a page polls 3 times a second)


class StationServer:
    """Serve the station for `backend` and `control` in a background thread.

    Parameters
    ----------
    backend : StationBackend, the cell loop's view (frame, outlines, proposal, teach).
    control : RunControl shared with the loop.
    host : interface to bind; 127.0.0.1 by default. Another address needs allow_remote=True.
    port : TCP port (0: any free port; see `.port`).
    token : the session token (default: a random one; see `.token` and `.url`).
    """

    def __init__(self, backend: StationBackend, control: RunControl, *, host: str = "127.0.0.1",
                 port: int = 8765, token: str | None = None, allow_remote: bool = False):
        if host not in LOOPBACK_HOSTS and not allow_remote:
            raise BadInput(f"binding the station to {host} exposes the arm to the network; "
                           "use 127.0.0.1 (default) or pass allow_remote / --allow-remote")
        check_token(token)
        self.backend = backend
        self.control = control
        self.token = token or new_token()
        self.session_id = secrets.token_hex(8)  # new at each start: a page tells a restart by it
        self.loopback_only = host in LOOPBACK_HOSTS
        handler = type("StationHandler", (_Handler,), {"station": self})
        try:
            self.httpd = _Server((host, port), handler)
        except OSError as e:
            raise _cannot_serve(host, port, e) from None
        self.httpd.daemon_threads = True
        self._thread: threading.Thread | None = None
        self._static_cache: dict[str, bytes] = {}

    @property
    def port(self) -> int:
        return self.httpd.server_address[1]

    @property
    def host(self) -> str:
        return self.httpd.server_address[0]

    @property
    def base_url(self) -> str:
        """The page's address on this machine (bound to every interface, 0.0.0.0 or ::, the loopback one: an
        address of 0.0.0.0 opens nothing; from another machine, this machine's own address)."""
        host = WILDCARD_HOSTS.get(self.host, self.host)
        host = host if ":" not in host else f"[{host}]"
        return f"http://{host}:{self.port}/"

    @property
    def on_every_interface(self) -> bool:
        return self.host in WILDCARD_HOSTS

    @property
    def url(self) -> str:
        """The page with the token in the fragment (never sent to the server, never logged)."""
        return f"{self.base_url}#token={self.token}"

    def static_file(self, name: str) -> bytes:
        if name not in self._static_cache:
            self._static_cache[name] = (resources.files("cell.station") / name).read_bytes()
        return self._static_cache[name]

    def state(self) -> dict:
        return {"session": self.session_id, "control": self.control.snapshot(), "cell": self.backend.snapshot()}

    def command(self, cmd: str, body: dict):
        """Apply one operator command (token already checked); returns the command's result."""
        rc = self.control
        by = "station"
        if cmd == "run":
            return rc.run(by=by)
        if cmd == "pause":
            return rc.pause(by=by)
        if cmd == "step":
            return rc.step(by=by)
        if cmd == "approve":
            return rc.approve(by=by, shown=_shown_proposal(body), shown_no=_shown_proposal_no(body))
        if cmd == "reject":
            shown = _shown_proposal(body)
            reason = body.get("reason", "")
            if not isinstance(reason, str):
                raise BadInput("'reason' must be a string")
            return rc.reject(reason[:500], by=by, shown=shown, shown_no=_shown_proposal_no(body))
        if cmd == "stop":
            reason = body.get("reason", "")
            before = rc.state
            state = rc.stop(reason[:500] if isinstance(reason, str) else "", by=by)
            halt = getattr(self.backend, "stop", None)
            if callable(halt) and before not in (STOPPED, DONE) and state == STOPPED:
                # quick-stop the arm now: a pick under way ends here, not at its end. Not once the run is over or
                # stopped already: a Stop a poll late (a second tab) sent a quick stop after a complete run's
                # summary, onto its recording's bus log, and its replay diverged
                halt()
            return state
        if cmd == "reset":
            return rc.reset(by=by)
        if cmd == "approval":
            required = body.get("required")
            if not isinstance(required, bool):
                raise BadInput("'required' must be true or false")
            return rc.set_require_approval(required, by=by)
        if cmd == "teach":
            part = body.get("part")
            if not isinstance(part, str) or not part:
                raise BadInput("'part' must be the id of a part on the current frame")
            p1, p2 = _point(body.get("p1_px"), "p1_px"), _point(body.get("p2_px"), "p2_px")
            rc.require_a_loop("teach")  # no next plan would learn it
            self._refuse_an_older_frame(_shown_frame(body))
            result = self.backend.teach(part, p1, p2)
            rc.log("teach", f"taught a grasp on {part}", part=part,
                   example=result.get("example_id") if isinstance(result, dict) else None)
            return result
        raise KeyError(f"no such command: {cmd}")

    def _refuse_an_older_frame(self, shown: int | None) -> None:
        """The teach's clicks are points on the frame the operator saw: on a later one the part may lie
        elsewhere or be gone (the backend checks its clicks against the frame it holds)."""
        current = self.backend.snapshot()["frame"]["index"]
        if shown is not None and shown != current:
            raise InvalidCommand(f"the frame taught on ({shown}) is no longer the current one (now {current}): "
                                 "nothing was taught; click the part and its contacts again on the new frame")

    # -- life cycle
    def start(self) -> StationServer:
        self._thread = threading.Thread(target=self.httpd.serve_forever, kwargs={"poll_interval": 0.05},
                                        name="station-http", daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        if self._thread is not None:
            self.httpd.shutdown()
            self._thread.join(timeout=5)
            self._thread = None
        self.httpd.server_close()

    def __enter__(self) -> StationServer:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()


def _shown_proposal(body: dict) -> dict | None:
    """The proposal the page showed when approve/reject was pressed (`proposal`, optional for scripts):
    RunControl refuses the decision (409) when another grasp waits by now, so a tap decides the grasp
    that was seen (a double tap, or a page a poll behind, would have decided the next one unseen)."""
    shown = body.get("proposal")
    if "proposal" in body and not isinstance(shown, dict):
        raise BadInput("'proposal' must be the proposal object shown (from /api/state)")
    return shown


def _shown_proposal_no(body: dict) -> int | None:
    """The number of the proposal the page showed (`proposal_no` of /api/state, optional): a repeat of
    the decision on it (a double tap) is answered as done, not refused."""
    return _index(body, "proposal_no", "the proposal_no of the grasp shown (from /api/state)")


def _shown_frame(body: dict) -> int | None:
    """The index of the frame a teach was clicked on (`frame`, optional for scripts)."""
    return _index(body, "frame", "the index of the frame the contacts were clicked on (from /api/state)")


def _index(body: dict, key: str, what: str) -> int | None:
    value = body.get(key)
    if key in body and (not isinstance(value, int) or isinstance(value, bool)):
        raise BadInput(f"'{key}' must be {what}")
    return value
