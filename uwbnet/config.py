"""TOML configuration of the deployment processes (``uwbnet node|fusion|simnode|record|replay``).

Each file is validated on load by the pydantic models below (unknown keys and wrong types are
rejected, durations carry a time unit or are plain seconds); a failure raises
:class:`ConfigError` with one line naming the file and the field. Precedence, in
:func:`load_config` only: command line > ``UWBNET_*`` environment > TOML > defaults.

Example node file (see ``deploy/examples/`` for all three)::

    net = "foyer"
    node = "b1"
    [zenoh]
    mode = "client"
    connect = ["tls/fusion.local:7447"]
    lease = "750 ms"
    [zenoh.tls]
    ca = "/etc/uwbnet/certs/ca.pem"
    cert = "/etc/uwbnet/certs/b1.pem"
    key = "/etc/uwbnet/certs/b1.key"
    [driver]
    name = "serial"
    [driver.options]
    port = "/dev/ttyUSB0"
"""

from __future__ import annotations

import json
import logging
import os
import re
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, Literal, TypeVar

import zenoh
from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, ValidationError

from protocol.transport import session_config
from sim_nodes.scene import _one_line

log = logging.getLogger(__name__)

ID_PATTERN = r"^[A-Za-z0-9_-]+$"
_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "min": 60.0}


class ConfigError(ValueError):
    """A configuration file is missing, not TOML, or fails validation (one-line message)."""


def _seconds(value: Any) -> Any:
    """A duration: a number of seconds, or a string ``"<number> <unit>"`` with unit s, ms, us
    or min. Anything else is left for pydantic to reject."""
    if isinstance(value, str):
        m = re.fullmatch(r"\s*([-+0-9.eE]+)\s*([A-Za-z]+)\s*", value)
        if m is None:
            raise ValueError(f'not a duration: {value!r} (write e.g. 0.5 or "500 ms")')
        unit = m.group(2)
        if unit not in _UNITS:
            raise ValueError(f"unit {unit!r} is not a time unit (s, ms, us, min)")
        try:
            return float(m.group(1)) * _UNITS[unit]
        except ValueError:
            raise ValueError(f"not a duration: {value!r}") from None
    return value


Seconds = Annotated[float, BeforeValidator(_seconds), Field(gt=0, allow_inf_nan=False)]
NodeId = Annotated[str, Field(pattern=ID_PATTERN)]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, frozen=True)


class TlsModel(_Model):
    """``[zenoh.tls]``: mutual TLS. Every process of a network presents a certificate signed by
    the network's CA (``deploy/make-certs.sh``) and accepts only peers that do."""

    ca: str
    cert: str
    key: str
    verify_name: bool = Field(
        default=False,
        description="check the router's certificate names its host (needs DNS/IP SANs)",
    )


class AccessModel(_Model):
    """``[zenoh.access]`` (router only): zenoh access control by certificate common name.

    ``members`` (the fusion center, node agents, recorders) may publish and subscribe anything
    of the network; ``viewers`` may only subscribe to ``fusion/**``; anyone else is denied,
    even with a certificate of the CA."""

    members: list[NodeId]
    viewers: list[NodeId] = Field(default_factory=list)


class ZenohModel(_Model):
    """``[zenoh]``: how this process joins the network."""

    mode: Literal["peer", "client", "router"] = "peer"
    listen: list[str] = Field(default_factory=list)
    connect: list[str] = Field(default_factory=list)
    lease: Seconds = Field(
        default=0.75,
        description="link lease: a silent peer or cut link is dropped (and its liveliness "
        "tokens with it) after this; shorter notices faster but drops flaky wifi links sooner",
    )
    reconnect: Seconds = Field(
        default=1.0, description="longest wait between attempts to re-attach a lost link"
    )
    multicast_scouting: bool = False
    shared_memory: bool = False
    config_file: str | None = None
    tls: TlsModel | None = None
    access: AccessModel | None = None


class DriverModel(_Model):
    """``[driver]``: the radar driver back-end (``node_agent.drivers``) and its options."""

    name: str = "serial"
    options: dict[str, Any] = Field(default_factory=dict)


class NodeDescModel(_Model):
    """``[describe]``: where the radar is (the device does not know)."""

    role: Literal["anchor", "bat", "robot", "illuminator", "observer"] = "bat"
    pose: Annotated[list[float], Field(min_length=4, max_length=4)] = Field(
        default_factory=lambda: [0.0, 0.0, 0.0, 0.0]
    )


class NodeFile(_Model):
    """``uwbnet node --config``: one node agent on a real (or any registered) radar driver."""

    net: NodeId = "demo"
    node: NodeId
    publish_ir: bool = True
    status_period: Seconds = 1.0
    describe: NodeDescModel = Field(default_factory=NodeDescModel)
    zenoh: ZenohModel = Field(default_factory=ZenohModel)
    driver: DriverModel = Field(default_factory=DriverModel)


class SimNodeFile(_Model):
    """``uwbnet simnode --config``: simulated nodes of a scenario, one node agent each.

    Scenario time 0 is the TDMA epoch of the fusion center's schedule, so simulated nodes on
    several hosts (and a restarted one) see the same people at the same network time."""

    net: NodeId = "demo"
    scenario: str = "foyer3"
    seed: int = 1
    nodes: list[NodeId] = Field(default_factory=list, description="empty: every node")
    truth: bool = Field(default=False, description="also publish the simulator's truth")
    publish_ir: bool = False
    status_period: Seconds = 1.0
    zenoh: ZenohModel = Field(default_factory=ZenohModel)


class WebModel(_Model):
    """``[web]``: the live web view served by the fusion center (docs/viewing.md)."""

    port: int = Field(8080, ge=0, le=65535, description="TCP port; 0: any free port")
    host: str = Field("127.0.0.1", description="address to bind; 0.0.0.0 opens it to the LAN")
    rate: float = Field(15.0, ge=1.0, le=60.0, description="page updates per second")
    scenario: str | None = Field(
        default=None, description="draw this scenario's walls as the floor plan (name or path)"
    )


class FusionFile(_Model):
    """``uwbnet fusion --config``: the fusion center (and, in router mode, the router)."""

    net: NodeId = "demo"
    service_id: NodeId = "fusion"
    method: Literal["gmphd", "image"] = "gmphd"
    frame_period: Seconds = 0.02
    tracks_jsonl: str | None = Field(
        default=None, description="also write every fusion update to this JSONL file"
    )
    web: WebModel | None = Field(default=None, description="serve the live web view")
    zenoh: ZenohModel = Field(default_factory=lambda: ZenohModel(mode="router"))


class RecordFile(_Model):
    """``uwbnet record|replay --config``: only the network name and how to join it."""

    net: NodeId = "demo"
    zenoh: ZenohModel = Field(default_factory=ZenohModel)


M = TypeVar("M", bound=_Model)

#: Environment variables and the config fields they override (``load_config``).
ENV_OVERRIDES = {
    "UWBNET_NET": ("net",),
    "UWBNET_CONNECT": ("zenoh", "connect"),
    "UWBNET_LISTEN": ("zenoh", "listen"),
    "UWBNET_MODE": ("zenoh", "mode"),
}


def _set(data: dict[str, Any], path: tuple[str, ...], value: Any) -> None:
    for part in path[:-1]:
        node = data.setdefault(part, {})
        if not isinstance(node, dict):
            return  # a wrong type in the file: validation reports it
        data = node
    data[path[-1]] = value


def load_config(
    model: type[M],
    path: str | os.PathLike[str] | None,
    overrides: Mapping[tuple[str, ...], Any] | None = None,
    env: Mapping[str, str] | None = None,
) -> M:
    """Read, merge and validate a configuration.

    Parameters
    ----------
    model : the file model (``NodeFile``, ``FusionFile``, ...).
    path : TOML file, or None for defaults only.
    overrides : command-line values by field path, e.g. ``{("zenoh", "connect"): [...]}``;
        None values are ignored.
    env : environment (default ``os.environ``); ``UWBNET_CONNECT``/``UWBNET_LISTEN`` are
        comma-separated endpoint lists.

    Raises
    ------
    ConfigError
        One line: ``file: field: message``.
    """
    source = "defaults"
    data: dict[str, Any] = {}
    if path is not None:
        source = str(path)
        try:
            with open(path, "rb") as f:
                data = tomllib.load(f)
        except OSError as exc:
            raise ConfigError(f"{source}: cannot read: {exc.strerror}") from None
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"{source}: not valid TOML: {exc}") from None
    env = os.environ if env is None else env
    for var, field_path in ENV_OVERRIDES.items():
        if var in env and field_path[0] in model.model_fields:
            value: Any = env[var]
            if field_path[-1] in ("connect", "listen"):
                value = [e.strip() for e in value.split(",") if e.strip()]
            _set(data, field_path, value)
    for field_path, value in (overrides or {}).items():
        if value is not None:
            _set(data, field_path, value)
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(f"{source}: {_one_line(exc)}") from None


def _check_file(what: str, path: str) -> str:
    """The path of a PEM file, checked now: zenoh reports a bad certificate only as a link
    that cannot be established, which a client would retry forever."""
    p = Path(path).expanduser()
    try:
        head = p.read_bytes()[:4096]
    except OSError as exc:
        raise ConfigError(f"zenoh.tls.{what}: cannot read {path}: {exc.strerror}") from None
    if b"-----BEGIN " not in head:
        raise ConfigError(f"zenoh.tls.{what}: {path} is not a PEM file")
    return str(p)


def access_control(access: AccessModel, net: str) -> dict[str, Any]:
    """The zenoh ``access_control`` section of a router for ``access`` (default deny)."""
    every = [
        "put",
        "delete",
        "declare_subscriber",
        "query",
        "reply",
        "declare_queryable",
        "liveliness_token",
        "liveliness_query",
        "declare_liveliness_subscriber",
    ]
    rules = [
        {
            "id": "member",
            "permission": "allow",
            "flows": ["ingress", "egress"],
            "messages": every,
            "key_exprs": [f"uwbnet/{net}/**"],
        },
        {
            "id": "viewer-subscribe",
            "permission": "allow",
            "flows": ["ingress"],
            "messages": ["declare_subscriber"],
            "key_exprs": [f"uwbnet/{net}/fusion/**"],
        },
        {
            "id": "viewer-receive",
            "permission": "allow",
            "flows": ["egress"],
            "messages": ["put"],
            "key_exprs": [f"uwbnet/{net}/fusion/**"],
        },
    ]
    subjects = [{"id": "members", "cert_common_names": list(access.members)}]
    policies = [{"rules": ["member"], "subjects": ["members"]}]
    if access.viewers:
        subjects.append({"id": "viewers", "cert_common_names": list(access.viewers)})
        policies.append({"rules": ["viewer-subscribe", "viewer-receive"], "subjects": ["viewers"]})
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


def zenoh_config(z: ZenohModel, net: str) -> zenoh.Config:
    """The zenoh session configuration of a ``[zenoh]`` section.

    With ``tls``, every endpoint must be ``tls/...``: zenoh would otherwise also accept
    plain TCP peers, which mutual TLS is there to keep out.
    """
    if z.tls is not None:
        plain = [e for e in [*z.listen, *z.connect] if not e.startswith("tls/")]
        if plain:
            raise ConfigError(f"zenoh: tls is configured but endpoint {plain[0]!r} is not tls/...")
    if z.tls is not None and z.mode != "client" and not z.listen:
        raise ConfigError(f"zenoh.listen: a {z.mode} with tls needs a tls/... listen endpoint")
    if z.access is not None and z.tls is None:
        raise ConfigError("zenoh.access: access control by certificate needs zenoh.tls")
    listen = z.listen
    if z.mode == "router" and not listen:
        listen = ["tcp/0.0.0.0:7447"]
    try:
        conf = session_config(
            mode=z.mode,
            listen=listen,
            connect=z.connect,
            multicast_scouting=z.multicast_scouting,
            shared_memory=z.shared_memory,
            lease_ms=max(1, round(z.lease * 1e3)),
            config_file=z.config_file,
        )
        # zenoh's default backs off to 4 s between attempts: a node whose link came back would
        # stay away for up to that long.
        retry = {
            "period_init_ms": min(250, round(z.reconnect * 1e3)),
            "period_max_ms": max(1, round(z.reconnect * 1e3)),
            "period_increase_factor": 2,
        }
        conf.insert_json5("connect/retry", json.dumps(retry))
        if z.tls is not None:
            ca, cert, key = (_check_file(w, getattr(z.tls, w)) for w in ("ca", "cert", "key"))
            tls = {
                "root_ca_certificate": ca,
                "enable_mtls": True,
                "verify_name_on_connect": z.tls.verify_name,
                "listen_certificate": cert,
                "listen_private_key": key,
                "connect_certificate": cert,
                "connect_private_key": key,
            }
            conf.insert_json5("transport/link/tls", json.dumps(tls))
            conf.insert_json5("transport/link/protocols", json.dumps(["tls"]))
        if z.access is not None:
            conf.insert_json5("access_control", json.dumps(access_control(z.access, net)))
    except ConfigError:
        raise
    except zenoh.ZError as exc:
        raise ConfigError(f"zenoh: {str(exc).splitlines()[0]}") from None
    except ValueError as exc:
        raise ConfigError(f"zenoh: {exc}") from None
    return conf
