"""Building blocks for a locked-down Zenoh session: user/password authentication and an
access-control rule set that decides who may publish odometry into the runtime.

Both are plain mappings for the pass-through fields of `config.schema.ZenohConfig`
(Zenoh 1.x configuration, checked against eclipse-zenoh 1.10):

```yaml
zenoh:
  listen: [tcp/192.168.1.10:7447]       # one interface, never 0.0.0.0
  extra:
    transport/auth/usrpwd:               # this session's credentials + who may connect
      user: litevloc
      password: "..."
      dictionary_file: /etc/litevloc/zenoh_users.txt   # "user:password" per line, mode 0600
  access_control:                        # = odometry_acl("odom", ["robot"])
    enabled: true
    default_permission: deny
    rules: [...]
```

A peer that fails authentication never gets a transport (nothing it sends arrives); an
authenticated peer is then filtered per message by the ACL (`put` ingress on the odometry
key only for the listed usernames). TLS (`zenoh.tls`, to `transport/link/tls`, with
`tls/...` endpoints) encrypts links and, with `enable_mtls: true`, authenticates peers
by client certificate; ACL subjects can then also match `cert_common_names`.
"""

from __future__ import annotations

from typing import Any


def usrpwd_auth(user: str | None = None, password: str | None = None,
                dictionary_file: str | None = None) -> dict[str, Any]:
    """`{"transport/auth/usrpwd": {...}}` for `ZenohConfig.extra`.

    `user`/`password`: the credentials this session presents; `dictionary_file`: the
    `user:password` lines this session accepts from connecting peers (the runtime side)."""
    if (user is None) != (password is None):
        raise ValueError("usrpwd_auth: give both user and password, or neither")
    block: dict[str, Any] = {}
    if user is not None:
        block.update(user=user, password=password)
    if dictionary_file is not None:
        block["dictionary_file"] = str(dictionary_file)
    if not block:
        raise ValueError("usrpwd_auth: nothing to configure")
    return {"transport/auth/usrpwd": block}


def odometry_acl(odometry_key: str, publishers: list[str], namespace: str = "",
                 subscribers: list[str] | None = None) -> dict[str, Any]:
    """An access-control block (default deny) for the runtime's session.

    * `put` of `odometry_key` INTO the runtime: only peers authenticated as one of
      `publishers` (usernames);
    * anyone connected may learn of the runtime's odometry subscription (so allowed
      publishers route to it) and may subscribe to `<namespace>/litevloc/**`, which the
      runtime publishes; with `subscribers` given, only those usernames may.
    Everything else (other keys, queries, puts on LiteVLoc's own topics from outside) is denied.
    """
    if not publishers:
        raise ValueError("odometry_acl: at least one publisher username is needed")
    ns = namespace.strip("/")
    out_keys = [f"{ns}/litevloc/**" if ns else "litevloc/**"]
    readers: dict[str, Any] = {"id": "readers"}
    if subscribers is not None:
        readers["usernames"] = list(subscribers)
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": [
            {"id": "odometry_in", "messages": ["put"], "flows": ["ingress"], "permission": "allow",
             "key_exprs": [odometry_key]},
            {"id": "odometry_sub", "messages": ["declare_subscriber"], "flows": ["egress"], "permission": "allow",
             "key_exprs": [odometry_key]},
            {"id": "litevloc_out", "messages": ["put"], "flows": ["egress"], "permission": "allow",
             "key_exprs": out_keys},
            {"id": "litevloc_sub", "messages": ["declare_subscriber"], "flows": ["ingress"], "permission": "allow",
             "key_exprs": out_keys},
        ],
        "subjects": [{"id": "odometry_publishers", "usernames": list(publishers)}, readers],
        "policies": [
            {"id": "odometry", "rules": ["odometry_in"], "subjects": ["odometry_publishers"]},
            {"id": "outputs", "rules": ["odometry_sub", "litevloc_out", "litevloc_sub"], "subjects": ["readers"]},
        ],
    }


def tls_config(root_ca_certificate: str, certificate: str | None = None, private_key: str | None = None,
               mtls: bool = True, listen: bool = True, verify_name_on_connect: bool = True) -> dict[str, Any]:
    """A `zenoh.tls` block (Zenoh's `transport/link/tls`) for `tls/HOST:PORT` endpoints.

    `root_ca_certificate`: PEM file of the CA that signed the other side's certificate (the
    server's for a connecting session; the clients' too with `mtls`). `certificate` /
    `private_key`: PEM files of this session's certificate, presented when it listens
    (`listen=True`: `listen_certificate`/`listen_private_key`) and, with `mtls`, also when it
    connects (`connect_certificate`/`connect_private_key`). With `mtls` a listening session
    refuses a peer that presents no certificate or one not signed by the CA (tested in
    tests/runtime/test_tls.py with generated certificates). The server certificate must
    name the host of the endpoint (subjectAltName) unless `verify_name_on_connect` is off.
    """
    if (certificate is None) != (private_key is None):
        raise ValueError("tls_config: give both certificate and private_key, or neither")
    if mtls and certificate is None:
        raise ValueError("tls_config: mutual TLS needs this session's certificate and private_key")
    block: dict[str, Any] = {"root_ca_certificate": str(root_ca_certificate), "enable_mtls": bool(mtls),
                             "verify_name_on_connect": bool(verify_name_on_connect)}
    if certificate is not None:
        if listen:
            block.update(listen_certificate=str(certificate), listen_private_key=str(private_key))
        if mtls or not listen:
            block.update(connect_certificate=str(certificate), connect_private_key=str(private_key))
    return block
