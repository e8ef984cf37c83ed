"""Who may do what on the bridge (issue 29, ``kali_daemons/bridge/access.py``): real Zenoh
sessions on 127.0.0.1, the bridge's router and its remote clients, with no authentication,
with usrpwd and with client certificates.

What refusal looks like to a client (Zenoh 1.10): without valid credentials ``zenoh.open``
raises ``ZError`` at once; a refused query or liveliness query ends at once with no reply (the
router answers it with a final message, not an error); a refused subscription, liveliness token
or put raises nothing and simply never reaches anyone.  A refused query is still processed in
order by the router, so a client's query is a barrier: whatever the client sent before it has
been routed, or dropped, by the time the query ends.
"""

from __future__ import annotations

import itertools
import shutil
import socket
import subprocess
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import zenoh
import zenoh.ext as zext

from kali_daemons.bridge.access import access_control, bridge_config
from kali_daemons.client.protocol import BridgeError
from kali_daemons.client.remote import common_name
from kali_daemons.client.zenohconfig import client_config
from kali_daemons.runtime.config import BridgeConfig, TlsConfig

INST = "t29"
P = f"kali/{INST}"
STATE = f"{P}/robots/left/state"
WAIT_S = 5.0  # for what must arrive
QUIET_S = 0.3  # for what must not: it would have arrived well within this
QUERY_TIMEOUT_S = 5.0  # a refused query must end long before it
PROMPT_S = 1.0  # "at once", with room for a loaded machine
EVENTS = ("event 0", "event 1", "event 2")
FORGERIES = itertools.count()  # each forged payload is new
USERS = {"op": "op-secret", "viewer": "viewer-secret", "stranger": "stranger-secret"}

Opener = Callable[[zenoh.Config], zenoh.Session]


def free_port() -> int:
    """A TCP port nobody on 127.0.0.1 listens on right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_for(predicate: Callable[[], bool], seconds: float = WAIT_S) -> bool:
    """Whether ``predicate`` turns true within ``seconds`` (polled every 10 ms)."""
    deadline = time.monotonic() + seconds
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


@pytest.fixture
def opened() -> Iterator[Opener]:
    """Opens Zenoh sessions and closes them all, the last opened first, after the test."""
    sessions: list[zenoh.Session] = []

    def open_session(config: zenoh.Config) -> zenoh.Session:
        session = zenoh.open(config)
        sessions.append(session)
        return session

    yield open_session
    for session in reversed(sessions):
        session.close()


class Bridge:
    """The bridge's side of the key space: its router session with the queryables, publishers
    and liveliness of ``kali/INST``, recording what reaches it."""

    def __init__(
        self, open_session: Opener, cfg: BridgeConfig, config: zenoh.Config | None = None
    ) -> None:
        self.session = open_session(config or bridge_config(cfg, INST))
        self.calls: list[str] = []  # keys its queryables were asked
        self.samples: list[str] = []  # payloads its own subscriber on kali/INST/** got
        self.tokens: list[tuple[str, zenoh.SampleKind]] = []  # remote clients' tokens
        self._keep = [
            self.session.declare_queryable(key, self._answer)
            for key in (
                f"{P}/user/*/status",
                f"{P}/user/*/config",
                f"{P}/user/*/verb/*",
                f"{P}/user/*/session/**",
            )
        ]
        self._keep.append(
            self.session.declare_subscriber(
                f"{P}/**", lambda s: self.samples.append(s.payload.to_string())
            )
        )
        self._keep.append(
            self.session.liveliness().declare_subscriber(
                f"{P}/user/*/clients/*", lambda s: self.tokens.append((str(s.key_expr), s.kind))
            )
        )
        self._keep.append(self.session.liveliness().declare_token(f"{P}/alive"))
        self.events = zext.declare_advanced_publisher(
            self.session,
            f"{P}/events",
            cache=zext.CacheConfig(max_samples=cfg.event_history),
            publisher_detection=True,
        )
        for event in EVENTS:
            self.events.put(event)

    def _answer(self, query: zenoh.Query) -> None:
        self.calls.append(str(query.key_expr))
        query.reply(query.key_expr, f"ok {query.key_expr}")

    def publishes_to(self, remote: Remote, seconds: float = WAIT_S) -> bool:
        """Whether a robot state the bridge keeps publishing reaches ``remote`` in time."""

        def arrived() -> bool:
            self.session.put(STATE, "state")
            return STATE in remote.got_keys()

        return wait_for(arrived, seconds)

    def token_seen(self, key: str, kind: zenoh.SampleKind) -> bool:
        """Whether the bridge's liveliness subscriber got ``key`` as ``kind``."""
        return (key, kind) in self.tokens


def reads(user: str) -> tuple[str, ...]:
    """The keys user ``user`` reads the bridge's answers on."""
    return (f"{P}/user/{user}/status", f"{P}/user/{user}/config")


def commands(user: str) -> tuple[str, ...]:
    """Keys of user ``user``'s commands: a verb, a session's open."""
    return (f"{P}/user/{user}/verb/enable", f"{P}/user/{user}/session/open")


class Remote:
    """A remote program: a client session subscribed to all of ``kali/INST``, asking under
    ``user``'s branch."""

    def __init__(self, session: zenoh.Session, user: str) -> None:
        self.session = session
        self.user = user
        self.samples: list[tuple[str, str]] = []
        self._sub = session.declare_subscriber(
            f"{P}/**", lambda s: self.samples.append((str(s.key_expr), s.payload.to_string()))
        )

    def got_keys(self) -> set[str]:
        return {key for key, _ in self.samples}

    def payloads(self) -> set[str]:
        return {payload for _, payload in self.samples}

    def ask(self, key: str) -> list[str]:
        """The payloads of the ok replies to a query on ``key``; a refused query must end at
        once (the router sends it a final message), not time out."""
        start = time.monotonic()
        replies = list(self.session.get(key, timeout=QUERY_TIMEOUT_S))
        assert time.monotonic() - start < PROMPT_S, f"query on {key} waited for its timeout"
        return [r.ok.payload.to_string() for r in replies if r.ok is not None]

    def alive(self) -> list[str]:
        """The liveliness tokens under ``kali/INST`` this session is told of (its own too)."""
        replies = self.session.liveliness().get(f"{P}/**", timeout=QUERY_TIMEOUT_S)
        return sorted(str(r.ok.key_expr) for r in replies if r.ok is not None)

    def barrier(self) -> None:
        """Return once the router has handled all this session sent before (see module doc)."""
        self.ask(f"{P}/status")


def event_history(session: zenoh.Session) -> list[str]:
    """The events an advanced subscriber declared now is given from the bridge's cache."""
    got: list[str] = []
    sub = zext.declare_advanced_subscriber(
        session,
        f"{P}/events",
        lambda s: got.append(s.payload.to_string()),
        history=zext.HistoryConfig(detect_late_publishers=True),
    )
    try:
        wait_for(lambda: len(got) >= len(EVENTS), QUIET_S * 3)
        return got
    finally:
        sub.undeclare()


def forged_put_is_dropped(bridge: Bridge, forger: Remote, other: Remote) -> None:
    """``forger``'s put on the events key reaches neither ``other`` nor the bridge (its own
    subscriber gets it: that is local to its session)."""
    forged = f"forged {next(FORGERIES)}"
    forger.session.put(f"{P}/events", forged)
    forger.barrier()  # the router has dropped it (or delivered it to the bridge's subscriber)
    other.barrier()  # and anything it forwarded to ``other`` came before this reply
    time.sleep(0.05)
    assert forged in forger.payloads()
    assert forged not in other.payloads()
    assert forged not in bridge.samples


def assert_reads(bridge: Bridge, remote: Remote) -> None:
    """``remote`` gets telemetry, status, config, the event history and liveliness."""
    assert bridge.publishes_to(remote)
    for key in reads(remote.user):
        assert remote.ask(key) == [f"ok {key}"]
    assert event_history(remote.session) == list(EVENTS)
    assert f"{P}/alive" in remote.alive()


def assert_commands(bridge: Bridge, remote: Remote, allowed: bool) -> None:
    """``remote``'s command queries are answered (allowed) or refused before the bridge."""
    mine = commands(remote.user)
    for key in mine:
        assert remote.ask(key) == ([f"ok {key}"] if allowed else [])
    assert [k for k in bridge.calls if k in mine] == (list(mine) if allowed else [])


def assert_token(
    bridge: Bridge, remote: Remote, name: str, allowed: bool, user: str | None = None
) -> zenoh.LivelinessToken:
    """``remote`` declares ``kali/INST/user/USER/clients/NAME`` (``user``: its own, by
    default); the bridge notices it iff allowed."""
    key = f"{P}/user/{user or remote.user}/clients/{name}"
    token = remote.session.liveliness().declare_token(key)
    if allowed:
        assert wait_for(lambda: bridge.token_seen(key, zenoh.SampleKind.PUT))
    else:
        remote.barrier()
        time.sleep(0.05)
        assert key not in {k for k, _ in bridge.tokens}
    return token


def assert_nothing(bridge: Bridge, remote: Remote, other: Remote, name: str) -> None:
    """``remote`` (a session in no role) can do nothing at all."""
    calls = list(bridge.calls)
    assert not bridge.publishes_to(remote, QUIET_S)
    for key in reads(remote.user):
        assert remote.ask(key) == []
    assert_commands(bridge, remote, allowed=False)
    assert bridge.calls == calls
    assert event_history(remote.session) == []
    assert remote.alive() == []
    assert_token(bridge, remote, name, allowed=False)
    forged_put_is_dropped(bridge, remote, other)


@pytest.fixture
def users_file(tmp_path: Path) -> Path:
    """Zenoh's usrpwd dictionary: one ``user:password`` a line."""
    path = tmp_path / "users"
    path.write_text("".join(f"{user}:{password}\n" for user, password in USERS.items()))
    return path


def usrpwd_bridge(opened: Opener, users_file: Path) -> tuple[Bridge, str]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    cfg = BridgeConfig(
        listen=(endpoint,), users_file=str(users_file), operators=("op",), readers=("viewer",)
    )
    return Bridge(opened, cfg), endpoint


def login(opened: Opener, endpoint: str, user: str) -> Remote:
    return Remote(opened(client_config(endpoint, user, USERS[user])), user)


def assert_others_refused(bridge: Bridge, remote: Remote, other: str) -> None:
    """Nothing ``remote`` asks or declares under user ``other``'s branch, nor under every
    user's at once, reaches the bridge."""
    calls = list(bridge.calls)
    for key in (*reads(other), *commands(other), f"{P}/user/*/status", f"{P}/user/**"):
        assert remote.ask(key) == [], key
    assert bridge.calls == calls
    assert_token(bridge, remote, "forged", allowed=False, user=other)


# --------------------------------------------------------------------------------------------
# The configs themselves


def test_bridge_config_is_a_router_with_default_deny() -> None:
    cfg = BridgeConfig(listen=("tcp/127.0.0.1:7447",))
    config = bridge_config(cfg, INST)
    assert config.get_json("mode") == '"router"'
    assert config.get_json("scouting/multicast/enabled") == "false"
    assert config.get_json("scouting/gossip/enabled") == "false"
    assert config.get_json("timestamping/enabled") == "true"
    assert config.get_json("access_control/enabled") == "true"
    assert config.get_json("access_control/default_permission") == '"deny"'
    acl = access_control(cfg, INST)
    assert acl["subjects"] == [{"id": "everyone"}]  # unauthenticated: all are operators
    assert [p["id"] for p in acl["policies"]] == ["operators"]
    assert {"commands-*", "programs-*"} <= set(acl["policies"][0]["rules"])  # any branch
    # no rule anywhere lets a remote session put or delete
    assert not any(
        {"put", "delete"} & set(r["messages"]) for r in acl["rules"] if "ingress" in r["flows"]
    )


def test_access_control_roles_follow_the_authentication() -> None:
    tls = TlsConfig("/x/cert.pem", "/x/key.pem", "/x/ca.pem")
    both = BridgeConfig(users_file="/x/users", tls=tls, operators=("op",), readers=("viewer",))
    acl = access_control(both, INST)
    assert acl["subjects"] == [
        {"id": "op-by-user", "usernames": ["op"]},
        {"id": "op-by-certificate", "cert_common_names": ["op"]},
        {"id": "viewer-by-user", "usernames": ["viewer"]},
        {"id": "viewer-by-certificate", "cert_common_names": ["viewer"]},
    ]
    op, viewer = acl["policies"]
    assert (op["id"], op["subjects"]) == ("operator-op", ["op-by-user", "op-by-certificate"])
    assert viewer["id"] == "reader-viewer"
    assert {"reads-op", "commands-op", "programs-op"} <= set(op["rules"])
    rules = {r["id"]: r for r in acl["rules"]}
    assert rules["commands-op"]["key_exprs"] == [f"{P}/user/op/verb/*", f"{P}/user/op/session/**"]
    reads = [f"{P}/user/viewer/{what}" for what in ("status", "config", "camera/*")]
    assert rules["reads-viewer"]["key_exprs"] == reads
    readers_only = BridgeConfig(users_file="/x/users", readers=("viewer",))
    acl = access_control(readers_only, INST)
    assert [p["id"] for p in acl["policies"]] == ["reader-viewer"]
    assert "reads-viewer" in acl["policies"][0]["rules"]
    assert not any(r.startswith(("commands-", "programs-")) for r in acl["policies"][0]["rules"])


def test_client_config_needs_whole_credentials() -> None:
    config = client_config("tcp/127.0.0.1:7447", "op", "pw")
    assert config.get_json("mode") == '"client"'
    assert config.get_json("connect/endpoints") == '["tcp/127.0.0.1:7447"]'
    assert config.get_json("transport/auth/usrpwd/user") == '"op"'
    with pytest.raises(ValueError, match="user and password"):
        client_config("tcp/127.0.0.1:7447", "op")
    with pytest.raises(ValueError, match="certificate and private_key"):
        client_config("tls/127.0.0.1:7447", certificate="/x/c.pem")


# --------------------------------------------------------------------------------------------
# No authentication: loopback only, every session an operator


def test_unauthenticated_sessions_read_and_command_but_cannot_put(opened: Opener) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    bridge = Bridge(opened, BridgeConfig(listen=(endpoint,)))
    first, second = (Remote(opened(client_config(endpoint)), n) for n in ("first", "second"))
    assert_reads(bridge, first)
    bridge.session.put(f"{P}/timing", "timing")
    assert wait_for(lambda: f"{P}/timing" in first.got_keys())
    assert_commands(bridge, first, allowed=True)
    assert_token(bridge, first, "first", allowed=True)
    assert_token(bridge, first, "as-second", allowed=True, user="second")  # a name it chose
    forged_put_is_dropped(bridge, second, first)
    forged_put_is_dropped(bridge, first, second)


def test_without_access_control_the_forged_put_would_arrive(opened: Opener) -> None:
    """The control for ``forged_put_is_dropped``: it is the access control that drops it."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    config = bridge_config(BridgeConfig(listen=(endpoint,)), INST)
    config.insert_json5("access_control/enabled", "false")
    bridge = Bridge(opened, BridgeConfig(listen=(endpoint,)), config)
    forger, other = (Remote(opened(client_config(endpoint)), n) for n in ("forger", "other"))
    assert bridge.publishes_to(other)
    forger.session.put(f"{P}/events", "forged")
    assert wait_for(lambda: "forged" in other.payloads() and "forged" in bridge.samples)


# --------------------------------------------------------------------------------------------
# usrpwd


@pytest.mark.parametrize(
    ("user", "password"),
    [(None, None), ("op", "wrong"), ("ghost", "op-secret")],
    ids=["no-credentials", "wrong-password", "unknown-user"],
)
def test_usrpwd_refuses_to_open_without_valid_credentials(
    opened: Opener, users_file: Path, user: str | None, password: str | None
) -> None:
    bridge, endpoint = usrpwd_bridge(opened, users_file)
    start = time.monotonic()
    with pytest.raises(zenoh.ZError, match="Unable to connect"):
        opened(client_config(endpoint, user, password))
    assert time.monotonic() - start < PROMPT_S
    assert bridge.tokens == [] and bridge.calls == []


def test_usrpwd_reader_reads_but_cannot_command(opened: Opener, users_file: Path) -> None:
    bridge, endpoint = usrpwd_bridge(opened, users_file)
    viewer = login(opened, endpoint, "viewer")
    op = login(opened, endpoint, "op")
    assert_reads(bridge, viewer)
    assert_commands(bridge, viewer, allowed=False)
    assert bridge.calls == list(reads("viewer"))
    assert_token(bridge, viewer, "viewer", allowed=False)
    forged_put_is_dropped(bridge, viewer, op)
    assert_others_refused(bridge, viewer, "op")
    # it sees the operators' programs come and go
    token = op.session.liveliness().declare_token(f"{P}/user/op/clients/program")
    assert wait_for(lambda: f"{P}/user/op/clients/program" in viewer.alive())
    token.undeclare()
    assert wait_for(lambda: f"{P}/user/op/clients/program" not in viewer.alive())


def test_usrpwd_operator_commands_and_its_death_is_noticed(
    opened: Opener, users_file: Path
) -> None:
    bridge, endpoint = usrpwd_bridge(opened, users_file)
    op = login(opened, endpoint, "op")
    viewer = login(opened, endpoint, "viewer")
    assert_reads(bridge, op)
    assert_commands(bridge, op, allowed=True)
    assert_token(bridge, op, "program", allowed=True)
    forged_put_is_dropped(bridge, op, viewer)
    assert_others_refused(bridge, op, "viewer")
    assert_others_refused(bridge, op, "viewer")
    op.session.close()  # the remote program dies: its token goes with its session
    key = f"{P}/user/op/clients/program"
    assert wait_for(lambda: bridge.token_seen(key, zenoh.SampleKind.DELETE))


def test_usrpwd_user_in_no_role_can_do_nothing(opened: Opener, users_file: Path) -> None:
    bridge, endpoint = usrpwd_bridge(opened, users_file)
    stranger = login(opened, endpoint, "stranger")
    op = login(opened, endpoint, "op")
    assert_nothing(bridge, stranger, op, "stranger")


# --------------------------------------------------------------------------------------------
# TLS with client certificates


def openssl(*args: str | Path) -> None:
    subprocess.run(["openssl", *map(str, args)], check=True, capture_output=True)


def make_pki(directory: Path, clients: tuple[str, ...]) -> dict[str, Path]:
    """A CA, a server certificate for localhost/127.0.0.1 and a client certificate for each
    common name in ``clients``: {name: PEM path}, keys at ``NAME.key`` beside them."""
    ec = ("-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes")
    ca, ca_key = directory / "ca.pem", directory / "ca.key"
    openssl(
        "req",
        "-x509",
        *ec,
        "-keyout",
        ca_key,
        "-out",
        ca,
        "-days",
        "1",
        "-subj",
        "/CN=kali test CA",
        "-addext",
        "basicConstraints=critical,CA:TRUE",
        "-addext",
        "keyUsage=critical,keyCertSign",
    )
    pems = {"ca": ca}
    for name, cn, ext in [
        (
            "server",
            "localhost",
            "subjectAltName=DNS:localhost,IP:127.0.0.1\nextendedKeyUsage=serverAuth\n",
        ),
        *((c, c, "extendedKeyUsage=clientAuth\n") for c in clients),
    ]:
        csr, ext_file = directory / f"{name}.csr", directory / f"{name}.ext"
        ext_file.write_text(ext + "basicConstraints=CA:FALSE\n")
        openssl(
            "req",
            "-new",
            *ec,
            "-keyout",
            directory / f"{name}.key",
            "-out",
            csr,
            "-subj",
            f"/CN={cn}",
        )
        pems[name] = directory / f"{name}.pem"
        openssl(
            "x509",
            "-req",
            "-in",
            csr,
            "-CA",
            ca,
            "-CAkey",
            ca_key,
            "-CAcreateserial",
            "-out",
            pems[name],
            "-days",
            "1",
            "-extfile",
            ext_file,
        )
    return pems


def test_tls_client_certificate_names_are_roles(opened: Opener, tmp_path: Path) -> None:
    if shutil.which("openssl") is None:
        pytest.skip("the openssl command line is needed to make the test certificates")
    pems = make_pki(tmp_path, ("op", "viewer", "stranger"))
    endpoint = f"tls/127.0.0.1:{free_port()}"
    tls = TlsConfig(str(pems["server"]), str(tmp_path / "server.key"), str(pems["ca"]))
    cfg = BridgeConfig(listen=(endpoint,), tls=tls, operators=("op",), readers=("viewer",))
    bridge = Bridge(opened, cfg)

    def connect(name: str | None) -> Remote:
        files = (
            {}
            if name is None
            else {"certificate": str(pems[name]), "private_key": str(tmp_path / f"{name}.key")}
        )
        session = opened(client_config(endpoint, root_ca=str(pems["ca"]), **files))
        return Remote(session, name or "nobody")

    with pytest.raises(zenoh.ZError, match="Unable to connect"):
        connect(None)  # no client certificate: the TLS handshake fails
    viewer, op, stranger = connect("viewer"), connect("op"), connect("stranger")
    assert_reads(bridge, viewer)
    assert_commands(bridge, viewer, allowed=False)
    assert_token(bridge, viewer, "viewer", allowed=False)
    forged_put_is_dropped(bridge, viewer, op)
    assert_nothing(bridge, stranger, op, "stranger")
    bridge.calls.clear()
    assert_commands(bridge, op, allowed=True)
    assert_token(bridge, op, "program", allowed=True)
    forged_put_is_dropped(bridge, op, viewer)
    assert_others_refused(bridge, op, "viewer")


def test_a_remote_program_goes_by_its_certificates_common_name(tmp_path: Path) -> None:
    """A remote ``Kali`` with a client certificate asks under the user its common name is."""
    if shutil.which("openssl") is None:
        pytest.skip("the openssl command line is needed to make the test certificates")
    pems = make_pki(tmp_path, ("op",))
    assert common_name(str(pems["op"])) == "op"
    with pytest.raises(BridgeError, match="cannot read certificate"):
        common_name(str(tmp_path / "nowhere.pem"))
