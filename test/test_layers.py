"""Issue 17.3: the package's folders are its layers, and imports point one way (down)."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "ros2_mos"

#: Each layer may import its own and the lower ones only.
LAYERS = {"core": 0, "io": 1, "sim": 2, "scoring": 3, "training": 4, "apps": 4, "offline": 4, "ros": 5, "tools": 6,
          "cli": 7}


def _imports(path: Path) -> list[tuple[int, str]]:
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.append((node.lineno, node.module))
        elif isinstance(node, ast.Import):
            out.extend((node.lineno, alias.name) for alias in node.names)
    return out


def test_every_module_sits_in_a_layer():
    loose = sorted(p.name for p in PACKAGE.glob("*.py") if p.name != "__init__.py")
    assert loose == [], f"modules outside the layer folders: {loose}"
    folders = {p.name for p in PACKAGE.iterdir() if (p / "__init__.py").is_file()}
    assert folders == set(LAYERS), folders ^ set(LAYERS)


def test_imports_point_down_the_layers():
    upward = []
    for path in PACKAGE.rglob("*.py"):
        layer = path.relative_to(PACKAGE).parts[0]
        if layer not in LAYERS:
            continue
        for line, module in _imports(path):
            parts = module.split(".")
            if parts[0] == "ros2_mos" and len(parts) > 1 and LAYERS.get(parts[1], -1) > LAYERS[layer]:
                upward.append(f"{path.relative_to(PACKAGE.parent)}:{line} ({layer}) imports {module}")
    assert upward == []
