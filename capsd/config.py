"""Configuration: YAML files validated into frozen Structs; errors name file, key path and line.

Degrees appear only in files (fields named `*_deg`); code converts them once, at load time,
through the typed accessors on the config Structs.
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Annotated, Any, Literal, TypeVar

import msgspec
import yaml

from capsd.errors import ConfigError, KeyExprError
from capsd.keys import check_name

C = TypeVar("C", bound=msgspec.Struct)

_ENDPOINT = re.compile(
    r"^(tcp|udp|tls|quic|ws)/(\[[0-9a-fA-F:.]+\]|[A-Za-z0-9_.-]+):\d{1,5}$|^unixsock-stream/.+$"
)
_PATH_TOKEN = re.compile(r"\.([A-Za-z_][A-Za-z0-9_]*)|\[(\d+)\]")
_MSGSPEC_AT = re.compile(r"^(?P<reason>.*?)(?: - at `(?P<path>\$[^`]*)`)?$", re.S)

Seconds = Annotated[float, msgspec.Meta(gt=0.0, le=3600.0)]


class ConfigSection(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Base of config Structs: unknown keys are errors, floats must be finite."""

    def __post_init__(self) -> None:
        for name in self.__struct_fields__:
            value = getattr(self, name)
            if isinstance(value, float) and not math.isfinite(value):
                raise ValueError(f"`{name}` must be a finite number, got {value}")


class TlsConfig(ConfigSection, frozen=True, kw_only=True):
    """Mutual TLS: the site's CA, this process's certificate and key.

    The certificate's common name is the identity the router's access control grants rights to.
    """

    ca_certificate: str
    certificate: str
    private_key: str
    verify_name: Literal["on", "off"] = "on"  # the router's certificate must name its host

    def __post_init__(self) -> None:
        super().__post_init__()
        for field in ("ca_certificate", "certificate", "private_key"):
            path = getattr(self, field)
            if not Path(path).is_file():
                raise ValueError(f"`{field}`: no such file '{path}'")


class BusConfig(ConfigSection, frozen=True, kw_only=True):
    """How a process joins Zenoh: its mode, endpoints, scouting and security."""

    mode: Literal["client", "peer", "router"] = "client"
    # BlueOS runs a router here; a service joins it rather than starting another.
    connect: tuple[str, ...] = ("tcp/127.0.0.1:7447",)
    listen: tuple[str, ...] = ()
    multicast_scouting: Literal["off", "on"] = "off"
    # Each connection attempt waits this long; the runner retries until stopped.
    connect_timeout_s: Annotated[float, msgspec.Meta(gt=0.0, le=60.0)] = 1.0
    # Reconnect back-off ceiling after a link loss (FIELD-NOTES: 0.5 s gives ~0.2 s recovery).
    reconnect_max_s: Annotated[float, msgspec.Meta(gt=0.0, le=60.0)] = 0.5
    # Between computers: tls/ endpoints with mutual TLS (deploy/security/make-site-certs.sh).
    tls: TlsConfig | None = None
    # Routers: Zenoh's access_control object as a JSON5 file (deploy/security/).
    access_control_file: str | None = None
    # The largest message this process accepts from a link (Zenoh's default is 1 GiB: a
    # denied or hostile put would be held whole first). A sonar frame is at most 512 beams x
    # 1500 bins x 2 bytes plus its header (capsd.topics.MAX_FRAME_BYTES).
    max_message_bytes: Annotated[int, msgspec.Meta(ge=65_536, le=64 * 1024 * 1024)] = 2_097_152

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.access_control_file is not None and not Path(self.access_control_file).is_file():
            raise ValueError(f"`access_control_file`: no such file '{self.access_control_file}'")
        for field, endpoints in (("connect", self.connect), ("listen", self.listen)):
            for i, endpoint in enumerate(endpoints):
                if not _ENDPOINT.fullmatch(endpoint):
                    raise ValueError(
                        f"`{field}[{i}]` '{endpoint}' is not a Zenoh endpoint "
                        "like 'tcp/127.0.0.1:7447'"
                    )
        if self.mode == "client" and not self.connect:
            raise ValueError("a client needs at least one `connect` endpoint")
        if self.mode == "router" and not self.listen:
            raise ValueError("a router needs at least one `listen` endpoint")


LogLevel = Literal["debug", "info", "warning", "error"]


class ServiceConfig(ConfigSection, frozen=True, kw_only=True):
    """Settings every service has; each service's config subclasses this."""

    site: str = "tank"
    vehicle: str = "topside"
    bus: BusConfig = BusConfig()
    health_period_s: Annotated[float, msgspec.Meta(ge=0.1, le=60.0)] = 1.0
    log_level: LogLevel = "info"
    log_to_bus: Literal["on", "off"] = "on"

    def __post_init__(self) -> None:
        super().__post_init__()
        try:
            check_name("site", self.site)
            check_name("vehicle", self.vehicle)
        except KeyExprError as exc:
            field = "site" if str(exc).startswith("site") else "vehicle"
            raise ValueError(f"`{field}`: {exc}") from None


_BOOL_TAG = "tag:yaml.org,2002:bool"


def _unique_key_loader() -> type[yaml.SafeLoader]:
    """A SafeLoader that refuses duplicate mapping keys (YAML would keep the last silently).

    Booleans are YAML 1.2's, true and false only: YAML 1.1 also reads a bare on/off/yes/no as
    one, so `mode: off` for a choice named "off" would be refused as "expected str, got bool".
    """

    class Loader(yaml.SafeLoader):
        pass

    Loader.yaml_implicit_resolvers = {
        first: [(tag, regexp) for tag, regexp in resolvers if tag != _BOOL_TAG]
        for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()
    }
    Loader.add_implicit_resolver(
        _BOOL_TAG, re.compile(r"^(?:true|True|TRUE|false|False|FALSE)$"), list("tTfF")
    )

    def construct_mapping(loader: yaml.SafeLoader, node: yaml.MappingNode) -> dict[Any, Any]:
        seen: set[Any] = set()
        for key_node, _ in node.value:
            key = loader.construct_object(key_node)
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    None, None, f"duplicate key '{key}'", key_node.start_mark
                )
            seen.add(key)
        return loader.construct_mapping(node)

    Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, construct_mapping)
    return Loader


def _line_of(root: yaml.Node | None, path: list[str | int]) -> int | None:
    """1-based line of the node at `path` in a composed YAML tree (deepest found)."""
    node = root
    line = node.start_mark.line + 1 if node is not None else None
    for part in path:
        if isinstance(node, yaml.MappingNode) and isinstance(part, str):
            match = next((v for k, v in node.value if getattr(k, "value", None) == part), None)
            if match is None:
                key = next((k for k, _ in node.value if getattr(k, "value", None) == part), None)
                return key.start_mark.line + 1 if key is not None else line
            node = match
        elif isinstance(node, yaml.SequenceNode) and isinstance(part, int):
            if part >= len(node.value):
                return line
            node = node.value[part]
        else:
            return line
        line = node.start_mark.line + 1
    return line


def _split_error(message: str) -> tuple[str, list[str | int]]:
    """Turn msgspec's 'reason - at `$.a.b[0]`' into (reason, ['a', 'b', 0])."""
    match = _MSGSPEC_AT.match(message)
    assert match is not None
    reason, raw_path = match.group("reason"), match.group("path") or "$"
    path: list[str | int] = []
    for name, index in _PATH_TOKEN.findall(raw_path[1:]):
        path.append(name if name else int(index))
    unknown = re.match(r"Object contains unknown field `([^`]+)`", reason)
    if unknown:
        path.append(unknown.group(1))
        reason = "unknown key (not part of this service's configuration)"
    # Our own __post_init__ checks start with the offending field: "`connect[1]` ..."
    field = re.match(r"^`([A-Za-z_][A-Za-z0-9_]*)(?:\[(\d+)\])?`:? ?", reason)
    if field:
        path.append(field.group(1))
        if field.group(2) is not None:
            path.append(int(field.group(2)))
        reason = reason[field.end() :]
    return reason, path


def _dotted(path: list[str | int]) -> str:
    out = ""
    for part in path:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else part)
    return out


def parse_config(text: str, cls: type[C], *, source: str) -> C:
    """Validate YAML `text` into `cls`; raise ConfigError naming `source`, the key and the line."""
    try:
        data = yaml.load(text, Loader=_unique_key_loader())
        root = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = mark.line + 1 if mark is not None else None
        problem = getattr(exc, "problem", None) or str(exc)
        raise ConfigError(source, "", f"not valid YAML: {problem}", line=line) from None
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(source, "", f"expected a mapping at the top, got {type(data).__name__}")
    try:
        return msgspec.convert(data, cls, strict=True)
    except msgspec.ValidationError as exc:
        reason, path = _split_error(str(exc))
        raise ConfigError(source, _dotted(path), reason, line=_line_of(root, path)) from None


def load_config(path: Path | str, cls: type[C]) -> C:
    """Read and validate a YAML config file into `cls`."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(str(path), "", f"cannot read file: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise ConfigError(str(path), "", "file is not UTF-8 text") from None
    return parse_config(text, cls, source=str(path))


def dump_config(config: msgspec.Struct) -> str:
    """The config as YAML, every key spelled out (for `--print-config` and example files)."""
    return yaml.safe_dump(msgspec.to_builtins(config), sort_keys=False)
