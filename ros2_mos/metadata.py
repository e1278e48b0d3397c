"""What a model needs beside its weights, stored inside the ONNX file as JSON.

A model trained for 64 x 2048 HDL-64 scans with N = 8 residuals must not be fed
anything else: the pipeline reads this to build its input and to refuse mismatches.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from typing import Any

from ros2_mos.config import SensorConfig
from ros2_mos.errors import ModelError
from ros2_mos.features import DEFAULT_MEANS, DEFAULT_STDS, InputSetup

METADATA_KEY = "ros2_mos"
FORMAT_VERSION = 1


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
        return meta
