"""The import contract: layers point down only (core <- services, simulator <- tools)."""

from __future__ import annotations

import ast
from pathlib import Path

from tests.conftest import REPO

# The core: what every process needs (payloads, codec, keys, config, runner, geometry, the
# device protocols' bytes). Whatever capsd holds besides these and the two mapped folders is a
# tool (CLI, demo, benches, record/replay, live view, training, calibration, evaluation).
CORE = frozenset(
    {
        "capsd",
        "capsd.bus",
        "capsd.codec",
        "capsd.config",
        "capsd.echo_cell",
        "capsd.errors",
        "capsd.fan",
        "capsd.geometry",
        "capsd.health",
        "capsd.keys",
        "capsd.latency",
        "capsd.launch",
        "capsd.logs",
        "capsd.mailbox",
        "capsd.mounts",
        "capsd.ned",
        "capsd.payloads",
        "capsd.pose_lookup",
        "capsd.progress",
        "capsd.registry",
        "capsd.ros_messages",
        "capsd.runner",
        "capsd.sdnotify",
        "capsd.servo_motion",
        "capsd.signing",
        "capsd.sonar_geometry",
        "capsd.sonar_image",
        "capsd.sound_speed",
        "capsd.stop_signal",
        "capsd.tank",
        "capsd.topics",
    }
)
PROTOCOLS = "capsd.protocols"
SERVICES = "capsd.services"
SIMULATOR = "capsd.simulator"
# Who may import whom; a tool may import anything.
MAY_IMPORT = {
    "core": {"core"},
    "services": {"core", "services"},
    "simulator": {"core", "simulator"},
    "tools": {"core", "services", "simulator", "tools"},
}


def layer_of(module: str) -> str:
    """The layer a capsd module belongs to."""
    if module in CORE or module == PROTOCOLS or module.startswith(PROTOCOLS + "."):
        return "core"
    if module.startswith(SERVICES + ".") or module == SERVICES:
        return "services"
    if module.startswith(SIMULATOR + ".") or module == SIMULATOR:
        return "simulator"
    return "tools"


def _service_of(module: str) -> str | None:
    parts = module.split(".")
    return parts[2] if module.startswith(SERVICES + ".") and len(parts) > 2 else None


def _modules() -> dict[str, Path]:
    """Every module of the installed package, by its import name."""
    out: dict[str, Path] = {}
    for folder, name in (("capsd", "capsd"), ("services", SERVICES), ("simulator", SIMULATOR)):
        root = REPO / folder
        for path in root.rglob("*.py"):
            relative = path.relative_to(root)
            if folder == "capsd" and relative.parts[0] in {"services", "simulator"}:
                continue  # the links to the two folders, walked under their own names
            parts = relative.with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join((name, *parts))] = path
    return out


def _imports(path: Path) -> set[str]:
    """The capsd modules `path` imports (at any depth: lazy imports count too)."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
    return {name for name in found if name == "capsd" or name.startswith("capsd.")}


def test_every_import_points_down() -> None:
    modules = _modules()
    assert len(modules) > 100
    broken = []
    for module, path in sorted(modules.items()):
        mine = layer_of(module)
        for target in sorted(_imports(path)):
            theirs = layer_of(target)
            if theirs not in MAY_IMPORT[mine]:
                broken.append(f"{module} ({mine}) imports {target} ({theirs})")
            elif mine == theirs == "services" and _service_of(module) != _service_of(target):
                broken.append(f"{module} imports another service's module {target}")
    assert not broken, "imports against the layers:\n" + "\n".join(broken)


def test_every_core_module_exists() -> None:
    # A name left in CORE after its module moved would silently make nothing core.
    modules = _modules()
    assert sorted(CORE - set(modules)) == []


def test_the_contract_can_fail() -> None:
    assert layer_of("capsd.bench.accuracy") == "tools"
    assert "tools" not in MAY_IMPORT[layer_of("capsd.services.locator.fix")]
    assert "services" not in MAY_IMPORT[layer_of("capsd.simulator.oculus_fake")]
    assert "tools" not in MAY_IMPORT[layer_of("capsd.protocols.oculus")]
