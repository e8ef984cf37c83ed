"""The Zenoh configs both ends of the bridge are built with: a remote program's session
(``client_config``: a client of one bridge only) and the settings the bridge's own router
shares with it (``insert_json``, ``no_scouting``; ``bridge.access`` builds the router's).
Outside any cycle.
"""

from __future__ import annotations

import json
from typing import Any

import zenoh


def insert_json(config: zenoh.Config, key: str, value: Any) -> None:
    """Set ``key`` of ``config`` to ``value``, given as JSON (a subset of JSON5)."""
    config.insert_json5(key, json.dumps(value))


def no_scouting(config: zenoh.Config) -> None:
    """No multicast or gossip scouting: a session talks to the endpoints it is given only.
    No shared-memory transport either: its /dev/shm files would outlive a session killed
    with SIGKILL (a run leaves nothing in /dev/shm), and the bridge's messages are small."""
    insert_json(config, "scouting/multicast/enabled", False)
    insert_json(config, "scouting/gossip/enabled", False)
    insert_json(config, "transport/shared_memory/enabled", False)


def client_config(
    endpoint: str,
    user: str | None = None,
    password: str | None = None,
    root_ca: str | None = None,
    certificate: str | None = None,
    private_key: str | None = None,
) -> zenoh.Config:
    """A remote program's Zenoh session: a client of the bridge at ``endpoint`` only.

    ``user``/``password`` log in with usrpwd; ``root_ca`` is the CA that signed the bridge's
    certificate (a ``tls/`` endpoint); ``certificate``/``private_key`` are the client's own for
    mutual TLS, whose common name is its user name."""
    if (user is None) != (password is None):
        raise ValueError("client_config: give both user and password, or neither")
    if (certificate is None) != (private_key is None):
        raise ValueError("client_config: give both certificate and private_key, or neither")
    config = zenoh.Config()
    insert_json(config, "mode", "client")
    insert_json(config, "connect/endpoints", [endpoint])
    no_scouting(config)
    if user is not None:
        insert_json(config, "transport/auth/usrpwd/user", user)
        insert_json(config, "transport/auth/usrpwd/password", password)
    if root_ca is not None:
        insert_json(config, "transport/link/tls/root_ca_certificate", root_ca)
    if certificate is not None:
        insert_json(config, "transport/link/tls/connect_certificate", certificate)
        insert_json(config, "transport/link/tls/connect_private_key", private_key)
        insert_json(config, "transport/link/tls/enable_mtls", True)
    return config
