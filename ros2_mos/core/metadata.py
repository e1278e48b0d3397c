"""What a model needs beside its weights, stored inside the ONNX file as JSON.

A model trained for 64 x 2048 HDL-64 scans with N = 8 residuals must not be fed
anything else: the pipeline reads this to build its input and to refuse mismatches.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable

from ros2_mos.core.config import ResidualConfig, SensorConfig
from ros2_mos.core.errors import ConfigError, ModelError
from ros2_mos.core.network_input import DEFAULT_MEANS, DEFAULT_STDS, InputSetup

METADATA_KEY = "ros2_mos"
FORMAT_VERSION = 1
#: A second ``metadata_props`` entry: the training config (its repository path, e.g. ``configs/x.yaml``) that made
#: the model. Provenance only: the pipeline never reads it.
TRAINING_CONFIG_KEY = "training_config"


@dataclass
class ModelMetadata:
    network: str
    input: InputSetup
    sensor: SensorConfig
    means: tuple[float, ...] = DEFAULT_MEANS
    stds: tuple[float, ...] = DEFAULT_STDS
    trained_on: str = ""
    valid_iou: float | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    format_version: int = FORMAT_VERSION

    def to_json(self) -> str:
        data = asdict(self)
        return json.dumps(data, sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> "ModelMetadata":
        try:
            data = json.loads(text)
            if data.get("format_version") != FORMAT_VERSION:
                raise ModelError(f"model metadata format {data.get('format_version')} is not {FORMAT_VERSION}")
            data["input"] = InputSetup(**data["input"])
            data["sensor"] = SensorConfig(**data["sensor"])
            data["means"] = tuple(data["means"])
            data["stds"] = tuple(data["stds"])
            meta = cls(**data)
        except ModelError:
            raise
        except (ValueError, KeyError, TypeError) as exc:
            raise ModelError(f"model metadata is malformed: {exc}") from None
        if len(meta.means) != 5 or len(meta.stds) != 5:
            raise ModelError("model metadata needs 5 means and 5 stds (r, x, y, z, e)")
        values = list(meta.means) + list(meta.stds)
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in values):
            raise ModelError(f"model metadata: means and stds must be finite numbers, got {meta.means}, {meta.stds}")
        if min(meta.stds) <= 0:
            raise ModelError(f"model metadata: stds must be positive, got {meta.stds}")
        if "recommended_threshold" in meta.extra:
            check_threshold(meta.extra["recommended_threshold"], "model metadata recommended_threshold")
        if "residual_max_range" in meta.extra:
            far = meta.extra["residual_max_range"]
            if far is None:  # the knob's "unset" (the model's own window) is not a window
                raise ModelError("model metadata residual_max_range: must be a number, got None")
            try:  # the residuals.max_range parameter's own limits
                ResidualConfig(max_range=far)
            except ConfigError as exc:
                raise ModelError(f"model metadata residual_max_range: {exc}") from None
        return meta

    @property
    def residual_max_range(self) -> float | None:
        """The residual window's far end the model was trained with (m); None for models that do not record it."""
        far = self.extra.get("residual_max_range")
        return None if far is None else float(far)


def check_threshold(value: object, what: str = "threshold") -> float:
    """A moving-probability threshold: a finite number strictly between 0 and 1."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 < float(value) < 1.0:
        raise ModelError(f"{what} must be a number in (0, 1), got {value!r}")
    return float(value)


def _load_model(path: Path, external_data: bool = True) -> Any:
    """The ONNX model proto of ``path``, or a ModelError saying why it cannot be read."""
    import onnx

    try:
        return onnx.load(str(path), load_external_data=external_data)
    except Exception as exc:  # onnx raises several types for unreadable files
        raise ModelError(f"cannot read model {path}: {exc}") from None


def write_recommended_threshold(path: str | Path, threshold: float) -> None:
    """Store ``recommended_threshold`` in an exported model's metadata (atomically replaces the file)."""
    threshold = check_threshold(threshold, "recommended_threshold")
    path = Path(path)
    proto = _load_model(path)
    entry = next((p for p in proto.metadata_props if p.key == METADATA_KEY), None)
    if entry is None:
        raise ModelError(f"{path} has no {METADATA_KEY} metadata (not exported by ros2-mos export)")
    meta = ModelMetadata.from_json(entry.value)
    meta.extra["recommended_threshold"] = threshold
    entry.value = meta.to_json()
    save_model_atomically(proto, path)


def read_training_config(path: str | Path) -> str | None:
    """The training config a model names in its ``training_config`` metadata entry; None if it names none."""
    proto = _load_model(Path(path), external_data=False)
    return next((p.value for p in proto.metadata_props if p.key == TRAINING_CONFIG_KEY), None)


def write_training_config(path: str | Path, config: str | Path) -> None:
    """Name the training config that made a model (atomically replaces the file; nothing else changes)."""
    config = Path(config).as_posix()
    if not config or config == ".":
        raise ModelError("training_config must be a non-empty path")
    path = Path(path)
    proto = _load_model(path)
    entry = next((p for p in proto.metadata_props if p.key == TRAINING_CONFIG_KEY), None)
    if entry is None:
        entry = proto.metadata_props.add()
        entry.key = TRAINING_CONFIG_KEY
    entry.value = config
    save_model_atomically(proto, path)


def save_model_atomically(proto: Any, path: Path, check: Callable[[Path], None] | None = None) -> None:
    """Write an ONNX ``proto`` beside ``path``, run ``check`` on that file, then rename it into place.

    A node never loads a half-written model, and a model that fails ``check`` never replaces the old one.
    """
    import onnx

    from ros2_mos.core.atomic import atomic_path

    with atomic_path(path) as tmp:  # a full disk: one OutputError line, neither file left half-written
        onnx.save(proto, tmp)
        if check is not None:
            check(tmp)
