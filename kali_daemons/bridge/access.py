"""Who may do what on the bridge: the Zenoh configs of the bridge and of its clients.

The bridge's session is a Zenoh router that remote programs connect to as clients; it alone
publishes under ``kali/INST/**``.  Zenoh's access control runs on the router, default deny,
and the rules only allow: readers subscribe and query their own status, config and camera
frames; operators also query their own verbs and sessions and declare their programs'
liveliness tokens; nobody puts or deletes, so no remote session can forge telemetry or
events.  A rule must include the whole key expression a message carries, so each user asks
and declares under its own name only and the bridge knows from a request's key who sent it.
Without authentication (loopback only) every session is an operator, on any branch.  The
rules one by one: docs/internals/motion-client-bridge.md.
"""

from __future__ import annotations

from typing import Any

import zenoh

from ..client.zenohconfig import insert_json, no_scouting
from ..runtime.config import BridgeConfig

MODE = "router"  # remote programs connect to the bridge as clients

# Zenoh's ACL message names (zenoh_config::AclMessage)
SUBSCRIBE = "declare_subscriber"
PUT = "put"
DELETE = "delete"
QUERY = "query"
REPLY = "reply"
TOKEN = "liveliness_token"
LIVELINESS_SUBSCRIBE = "declare_liveliness_subscriber"
LIVELINESS_QUERY = "liveliness_query"

COMMON_RULES = (
    "subscribe",
    "samples",
    "liveliness",
    "instances",
    "tokens",
    "history-queries",
    "replies",
)


def prefix(instance: str) -> str:
    """The key every key of Kali instance ``instance`` starts with: ``kali/INSTANCE``."""
    return f"kali/{instance}"


def _rule(rid: str, flow: str, messages: list[str], keys: list[str]) -> dict[str, Any]:
    return {
        "id": rid,
        "permission": "allow",
        "flows": [flow],
        "messages": messages,
        "key_exprs": keys,
    }


def access_rules(instance: str) -> list[dict[str, Any]]:
    """The Zenoh ACL rules (all ``allow``) every role has, ``COMMON_RULES``: reading the key
    space of ``instance``."""
    p = prefix(instance)
    everything = [f"{p}/**", f"{p}/**/@adv/**"]  # @adv: the advanced publishers' own keys
    return [
        _rule("subscribe", "ingress", [SUBSCRIBE], everything),
        _rule("samples", "egress", [PUT, DELETE], everything),
        _rule("liveliness", "ingress", [LIVELINESS_SUBSCRIBE, LIVELINESS_QUERY], everything),
        # which instances answer here (a client asking for one not here is told them)
        _rule("instances", "ingress", [LIVELINESS_QUERY], ["kali/*/alive"]),
        _rule("tokens", "egress", [TOKEN], everything),
        _rule("history-queries", "ingress", [QUERY], everything[1:]),
        _rule("replies", "egress", [REPLY], everything),
    ]


def user_rules(instance: str, user: str, command: bool) -> list[dict[str, Any]]:
    """The rules of user ``user``'s own branch (``*``: anyone's): ``reads-USER``, querying
    its status, config and cameras' frames; if it may ``command``, ``commands-USER``,
    querying its verbs and sessions, and ``programs-USER``, declaring its programs'
    liveliness tokens."""
    home = f"{prefix(instance)}/user/{user}"
    reads = [f"{home}/status", f"{home}/config", f"{home}/camera/*"]
    rules = [_rule(f"reads-{user}", "ingress", [QUERY], reads)]
    if command:
        rules += [
            _rule(f"commands-{user}", "ingress", [QUERY], [f"{home}/verb/*", f"{home}/session/**"]),
            _rule(f"programs-{user}", "ingress", [TOKEN], [f"{home}/clients/*"]),
        ]
    return rules


def _subjects(cfg: BridgeConfig, user: str) -> list[dict[str, Any]]:
    """The ACL subjects of one user: its name as a usrpwd user name and, separately, as a
    client certificate's common name (two subjects, so either identity alone is the user:
    one subject holding both would require both)."""
    subjects = []
    if cfg.users_file is not None:
        subjects.append({"id": f"{user}-by-user", "usernames": [user]})
    if cfg.tls is not None and cfg.tls.root_ca is not None:
        subjects.append({"id": f"{user}-by-certificate", "cert_common_names": [user]})
    return subjects


def access_control(cfg: BridgeConfig, instance: str) -> dict[str, Any]:
    """The ``access_control`` section of the bridge's Zenoh config (see the module doc): a
    policy per user, ``operator-USER`` or ``reader-USER``, with the rules every role has and
    those of the user's own branch; unauthenticated, one policy ``operators`` for everyone,
    on every branch."""
    rules = access_rules(instance)
    common = [r["id"] for r in rules]
    if not cfg.authenticated:  # loopback only: whoever gets here is a local user, who may command
        own = user_rules(instance, "*", command=True)
        return {
            "enabled": True,
            "default_permission": "deny",
            "rules": rules + own,
            "subjects": [{"id": "everyone"}],
            "policies": [
                {
                    "id": "operators",
                    "rules": common + [r["id"] for r in own],
                    "subjects": ["everyone"],
                }
            ],
        }
    subjects, policies = [], []
    for role, names in (("operator", cfg.operators), ("reader", cfg.readers)):
        for user in names:
            own = user_rules(instance, user, command=role == "operator")
            mine = _subjects(cfg, user)
            rules += own
            subjects += mine
            policies.append(
                {
                    "id": f"{role}-{user}",
                    "rules": common + [r["id"] for r in own],
                    "subjects": [s["id"] for s in mine],
                }
            )
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,  # none: Zenoh then denies everything
        "policies": policies,
    }


def bridge_config(cfg: BridgeConfig, instance: str) -> zenoh.Config:
    """The bridge's own Zenoh session: a router listening on ``cfg.listen`` and connecting to
    nothing, with timestamps (an advanced publisher's cache needs the session's clock), TLS,
    usrpwd authentication and the access control of ``access_control``."""
    config = zenoh.Config()
    insert_json(config, "mode", MODE)
    insert_json(config, "listen/endpoints", list(cfg.listen))
    insert_json(config, "connect/endpoints", [])
    no_scouting(config)
    # a router's open otherwise waits scouting/delay (500 ms) for peers it cannot find
    insert_json(config, "scouting/delay", 0)
    insert_json(config, "timestamping/enabled", True)
    if cfg.tls is not None:
        insert_json(config, "transport/link/tls/listen_certificate", cfg.tls.certificate)
        insert_json(config, "transport/link/tls/listen_private_key", cfg.tls.private_key)
        if cfg.tls.root_ca is not None:  # client certificates required, signed by this CA
            insert_json(config, "transport/link/tls/root_ca_certificate", cfg.tls.root_ca)
            insert_json(config, "transport/link/tls/enable_mtls", True)
    if cfg.users_file is not None:
        insert_json(config, "transport/auth/usrpwd/dictionary_file", cfg.users_file)
    insert_json(config, "access_control", access_control(cfg, instance))
    return config
