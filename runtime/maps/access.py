"""Who may do what on the map service: a Zenoh access-control block (default deny) for the
service's session, in the form of `runtime.transport.security.odometry_acl`.

* `readers` (and every writer and admin) may query the index, a map's latest, versions,
  manifests and chunks, and subscribe to announcements;
* `writers` may also push (the `push/**` queries); `admins` may also ask for a rollback;
* nobody may `put` or `delete` anything under `litevloc/maps/**` (the service declares no
  subscriber there either, and its store never rewrites a version);
* `allow_other`: key expressions on which the listed robots may do anything (their own topics,
  when the map service's session is the router the robots talk through).

Identities are Zenoh usernames (`transport/auth/usrpwd`, `security.usrpwd_auth`) or, with
`by="cert_common_name"`, the common names of mutual-TLS client certificates (`security.tls_config`).
"""

from __future__ import annotations

from typing import Any, Literal

from litevloc.runtime.maps.keys import ANNOUNCE_KEYS as ANNOUNCE
from litevloc.runtime.maps.keys import PUSH_KEYS, READ_KEYS, ROLLBACK_KEYS

ALL_MESSAGES = ["put", "delete", "declare_subscriber", "query", "declare_queryable", "reply", "liveliness_token",
                "declare_liveliness_subscriber", "liveliness_query"]


def _query_rules(rid: str, key_exprs: tuple[str, ...]) -> list[dict[str, Any]]:
    return [
        {"id": f"{rid}_query", "messages": ["query"], "flows": ["ingress"], "permission": "allow",
         "key_exprs": list(key_exprs)},
        {"id": f"{rid}_reply", "messages": ["reply"], "flows": ["egress"], "permission": "allow",
         "key_exprs": list(key_exprs)},
        {"id": f"{rid}_queryable", "messages": ["declare_queryable"], "flows": ["egress"], "permission": "allow",
         "key_exprs": list(key_exprs)},
    ]


def map_acl(readers: list[str], writers: list[str], admins: list[str] | None = None,
            by: Literal["username", "cert_common_name"] = "username",
            allow_other: list[str] | None = None) -> dict[str, Any]:
    """The `access_control` block for the map service's Zenoh session (see the module docstring).

    `admins` defaults to `writers`. Every name is a username or a certificate common name (`by`)."""
    if not (readers or writers):
        raise ValueError("map_acl: list at least one reader or writer")
    admins = list(writers) if admins is None else list(admins)
    attr = "usernames" if by == "username" else "cert_common_names"
    everyone = sorted(set(readers) | set(writers) | set(admins))
    rules = [
        *_query_rules("read", READ_KEYS),
        {"id": "announce_sub", "messages": ["declare_subscriber"], "flows": ["ingress"], "permission": "allow",
         "key_exprs": [ANNOUNCE]},
        {"id": "announce_put", "messages": ["put"], "flows": ["egress"], "permission": "allow",
         "key_exprs": [ANNOUNCE]},
        *_query_rules("push", PUSH_KEYS),
        *_query_rules("rollback", ROLLBACK_KEYS),
    ]
    subjects = [{"id": "map_readers", attr: everyone}]
    policies = [{"id": "read", "rules": ["read_query", "read_reply", "read_queryable", "announce_sub",
                                         "announce_put"], "subjects": ["map_readers"]}]
    if writers:
        subjects.append({"id": "map_writers", attr: sorted(writers)})
        policies.append({"id": "push", "rules": ["push_query", "push_reply", "push_queryable"],
                         "subjects": ["map_writers"]})
    if admins:
        subjects.append({"id": "map_admins", attr: sorted(admins)})
        policies.append({"id": "rollback", "rules": ["rollback_query", "rollback_reply", "rollback_queryable"],
                         "subjects": ["map_admins"]})
    if allow_other:
        rules.append({"id": "other", "messages": ALL_MESSAGES, "flows": ["ingress", "egress"], "permission": "allow",
                      "key_exprs": list(allow_other)})
        policies.append({"id": "other", "rules": ["other"], "subjects": ["map_readers"]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}
