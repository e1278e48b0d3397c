"""Running an exported MOS network with ONNX Runtime (no torch at run time).

The model file carries its own metadata (sensor, input setup, normalisation); a
file that is missing, truncated, without metadata, or whose input does not match
its metadata is refused here with a :class:`ModelError`, before any scan arrives.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import numpy as np

from ros2_mos.core.errors import ModelError
from ros2_mos.core.metadata import METADATA_KEY, ModelMetadata

DEFAULT_MODEL_NAME = "default.onnx"
INPUT_NAME = "input"
OUTPUT_NAME = "probability"

# Preferred ONNX Runtime providers, fastest first; the first available one is used.
PROVIDER_PREFERENCE = ("TensorrtExecutionProvider", "CUDAExecutionProvider", "CPUExecutionProvider")


def default_model_path(sensor: str | None = None) -> Path:
    """The model shipped inside the package for ``sensor`` (a preset name; found through package resources).

    ``models/<sensor>.onnx`` where one ships (``vlp16``, ``vlp32c``, ``os1-64``, ``os1-128``), else
    ``default.onnx`` (the HDL-64E's): a sensor without its own model gets a clear error from the
    pipeline, which compares the sensor with the one the model was trained for.
    """
    models = shipped_models()
    return models.get(sensor or "hdl64", models["hdl64"])


def shipped_models() -> dict[str, Path]:
    """Sensor name -> the model shipped for it (``hdl64`` -> ``default.onnx``)."""
    models = Path(str(resources.files("ros2_mos") / "models"))
    out = {"hdl64": models / DEFAULT_MODEL_NAME}
    out.update({p.stem: p for p in sorted(models.glob("*.onnx")) if p.name != DEFAULT_MODEL_NAME})
    return out


def read_metadata(path: str | Path) -> ModelMetadata:
    """Only the metadata of a model file (cheap: no session is created)."""
    import onnx

    path = _existing(path)
    try:
        model = onnx.load(str(path), load_external_data=False)
    except Exception as exc:  # onnx raises DecodeError and friends
        raise ModelError(f"{path}: not a readable ONNX model ({exc})") from None
    props = {p.key: p.value for p in model.metadata_props}
    if METADATA_KEY not in props:
        raise ModelError(f"{path}: no '{METADATA_KEY}' metadata (not exported by ros2-mos export)")
    return ModelMetadata.from_json(props[METADATA_KEY])


def _existing(path: str | Path) -> Path:
    path = Path(path)
    if not path.is_file():
        raise ModelError(f"model file not found: {path}")
    return path


class MosModel:
    """An ONNX Runtime session plus the metadata that says how to feed it."""

    def __init__(self, path: str | Path | None = None, intra_op_threads: int = 0, providers: list[str] | None = None):
        import onnxruntime as ort

        self.path = _existing(path if path is not None else default_model_path())
        options = ort.SessionOptions()
        options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        if intra_op_threads > 0:
            options.intra_op_num_threads = intra_op_threads
        options.inter_op_num_threads = 1
        options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        # ORT's worker threads spin after each run by default; the pipeline's other stages
        # (KISS-ICP, numpy) need those cores right after inference, so let the threads sleep.
        options.add_session_config_entry("session.intra_op.allow_spinning", "0")
        available = ort.get_available_providers()
        chosen = providers or [p for p in PROVIDER_PREFERENCE if p in available]
        try:
            self.session = ort.InferenceSession(str(self.path), sess_options=options, providers=chosen)
        except Exception as exc:  # onnxruntime raises its own exception types
            raise ModelError(f"{self.path}: ONNX Runtime cannot load it ({exc})") from None
        meta = self.session.get_modelmeta().custom_metadata_map
        if METADATA_KEY not in meta:
            raise ModelError(f"{self.path}: no '{METADATA_KEY}' metadata (not exported by ros2-mos export)")
        self.metadata = ModelMetadata.from_json(meta[METADATA_KEY])
        self.provider = self.session.get_providers()[0]
        self._check_signature()

    def _check_signature(self) -> None:
        inputs = self.session.get_inputs()
        if len(inputs) != 1 or inputs[0].name != INPUT_NAME:
            raise ModelError(f"{self.path}: expected one input named '{INPUT_NAME}', got {[i.name for i in inputs]}")
        shape = inputs[0].shape
        channels = shape[1] if len(shape) == 4 else None
        expected = self.metadata.input.channels
        if isinstance(channels, int) and channels != expected:
            raise ModelError(
                f"{self.path}: network takes {channels} input channels but its metadata "
                f"({self.metadata.input.label}) implies {expected}"
            )
        sensor = self.metadata.sensor
        hw = tuple(shape[2:]) if len(shape) == 4 else ()
        if len(hw) == 2 and all(isinstance(d, int) for d in hw) and hw != (sensor.height, sensor.width):
            raise ModelError(f"{self.path}: input is {hw[0]} x {hw[1]} "
                             f"but the metadata sensor is {sensor.height} x {sensor.width}")
        outputs = [o.name for o in self.session.get_outputs()]
        if OUTPUT_NAME not in outputs:
            raise ModelError(f"{self.path}: no output named '{OUTPUT_NAME}' (outputs: {outputs})")
        # One inference on zeros now, so that a graph that cannot run on this input (a channel mismatch
        # hidden by dynamic shapes, a head with one class) fails at load, not on every scan.
        probe = np.zeros((1, expected, sensor.height, sensor.width), np.float32)
        try:
            out = self.session.run([OUTPUT_NAME], {INPUT_NAME: probe})[0]
        except Exception as exc:  # onnxruntime raises its own exception types
            first = (str(exc).splitlines() or [""])[0][:160]
            raise ModelError(f"{self.path}: a test inference on a {expected} x {sensor.height} x {sensor.width} "
                             f"input failed ({first})") from None
        if out.shape != (1, 2, sensor.height, sensor.width):
            raise ModelError(f"{self.path}: output '{OUTPUT_NAME}' is {tuple(out.shape)}, expected (1, 2 classes, "
                             f"{sensor.height}, {sensor.width}): (static, moving) probabilities per pixel")

    @property
    def channels(self) -> int:
        return self.metadata.input.channels

    def predict(self, network_input: np.ndarray) -> np.ndarray:
        """(C, H, W) input -> (H, W) moving probability."""
        x = np.asarray(network_input, dtype=np.float32)
        if x.ndim != 3 or x.shape[0] != self.channels:
            raise ModelError(f"model expects ({self.channels}, H, W) input, got {x.shape}")
        out = self.session.run([OUTPUT_NAME], {INPUT_NAME: x[None]})[0]
        return np.ascontiguousarray(out[0, 1], dtype=np.float32)
