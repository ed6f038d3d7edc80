"""Serving the workbench with uvicorn: loopback by default, a token otherwise."""

from __future__ import annotations

import ipaddress
import secrets
import socket

__all__ = ["is_loopback", "url_for", "serve", "free_port"]


def is_loopback(host: str) -> bool:
    """Whether ``host`` (an address or ``localhost``) only accepts connections from this machine."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port free on ``host`` right now."""
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as s:
        s.bind((host.strip("[]"), 0))
        return int(s.getsockname()[1])


def url_for(host: str, port: int, token: str | None = None) -> str:
    h = f"[{host.strip('[]')}]" if ":" in host else host
    return f"http://{h}:{port}/" + (f"?token={token}" if token else "")


def allowed_hosts(host: str, port: int) -> tuple:
    """Host-header values the server answers to: its address (and loopback names when loopback)."""
    names = {host, host.strip("[]"), f"[{host.strip('[]')}]"}
    if is_loopback(host):
        names |= {"127.0.0.1", "localhost", "[::1]"}
    if host in ("0.0.0.0", "::"):
        # any address of this machine: the token is the guard
        names |= {socket.gethostname(), "127.0.0.1", "localhost"}
        try:
            names |= {a[4][0] for a in socket.getaddrinfo(socket.gethostname(), None)}
        except OSError:
            pass
    return tuple(sorted(n for n in names if n) + sorted(f"{n}:{port}" for n in names if n))


def serve(session, *, host: str = "127.0.0.1", port: int = 8765, allow_remote: bool = False, open_browser: bool = False,
          on_ready=None, sources=None, log_level: str = "warning"):
    """Run the workbench until interrupted.

    Parameters
    ----------
    session : Session
    host : str
        Address to bind. Anything but loopback needs ``allow_remote`` and then uses a token.
    port : int
    allow_remote : bool
        Permit a non-loopback ``host``: every request must then carry a random per-run token.
    open_browser : bool
        Open the page in the default browser once the server listens.
    on_ready : callable(url), optional
        Called with the page's URL (token included) once the server listens.
    """
    import threading
    import webbrowser

    import uvicorn

    from .app import create_app

    token = None
    if not is_loopback(host):
        if not allow_remote:
            raise ValueError(f"--host {host}: not a loopback address; serving beyond this machine needs "
                             "--allow-remote (and then a per-run token)")
        token = secrets.token_urlsafe(24)
    app = create_app(session, token=token, allowed_hosts=allowed_hosts(host, port), sources=sources)
    config = uvicorn.Config(app, host=host.strip("[]"), port=port, log_level=log_level, access_log=False,
                            limit_concurrency=64, timeout_keep_alive=5, h11_max_incomplete_event_size=64 * 1024)
    server = uvicorn.Server(config)
    wildcard = host.strip("[]") in ("0.0.0.0", "::")
    url = url_for(socket.gethostname() if wildcard else host, port, token)
    local_url = url_for("127.0.0.1", port, token) if wildcard or host == "localhost" else url

    def announce():
        import time

        while not server.started and not server.should_exit:
            time.sleep(0.05)
        if server.started:
            if on_ready is not None:
                on_ready(url)
            if open_browser:
                webbrowser.open(local_url)

    threading.Thread(target=announce, daemon=True).start()
    server.run()
    return url
