"""Network registry: every trainable architecture by name, for configs, checkpoints and metadata.

A checkpoint stores the name and constructor kwargs, so ``build_network`` is the only
way networks are created: what was trained is what gets exported.
"""

from __future__ import annotations

import importlib
from typing import Any

from torch import nn

from ros2_mos.core.errors import ConfigError

# name -> (module under ros2_mos.training.nets, class name); imported lazily so that
# building a small network does not import every architecture.
_REGISTRY: dict[str, tuple[str, str]] = {
    "fastmos": ("fastmos", "FastMOS"),
    "salsanext": ("salsanext", "SalsaNext"),
    "rangenet21": ("rangenet", "RangeNet21"),
    "rangenet53": ("rangenet", "RangeNet53"),
    "minet": ("minet", "MINet"),
}


def network_names() -> list[str]:
    """The names ``build_network`` accepts."""
    return sorted(_REGISTRY)


def build_network(name: str, in_channels: int, n_classes: int = 2, **kwargs: Any) -> nn.Module:
    """Build a registered network mapping (B, in_channels, H, W) to (B, n_classes, H, W) logits."""
    key = name.lower()
    if key not in _REGISTRY:
        raise ConfigError(f"unknown network {name!r}; known networks: {', '.join(network_names())}")
    if in_channels <= 0 or n_classes < 2:
        raise ConfigError(f"network {name!r}: need in_channels > 0 and n_classes >= 2, got {in_channels}, {n_classes}")
    module_name, class_name = _REGISTRY[key]
    module = importlib.import_module(f"ros2_mos.training.nets.{module_name}")
    try:
        return getattr(module, class_name)(in_channels, n_classes, **kwargs)
    except TypeError as exc:
        raise ConfigError(f"network {name!r}: bad options {kwargs}: {exc}") from None
