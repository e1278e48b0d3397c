"""Export a trained network to the ONNX model the core runtime loads without torch.

The exported graph is ``softmax(net(input))``: input ``"input"`` (1, C, H, W) float32,
output ``"probability"`` (1, n_classes, H, W) with channel 1 = moving.  For two classes
the softmax is written as ``p_moving = sigmoid(l_1 - l_0)``, ``p_static = 1 - p_moving``
(the same function): ONNX Runtime's CPU Softmax over the channel axis of an NCHW
tensor transposes it, a large share of the model's time (benchmarks/design_figures.md).  The model's
:class:`~ros2_mos.core.metadata.ModelMetadata` (setup, sensor, normalisation, network,
training data, valid IoU) is stored as JSON in the ONNX ``metadata_props`` under
:data:`~ros2_mos.core.metadata.METADATA_KEY`, so a model file is self-describing.

Every export is checked: ONNX Runtime must reproduce the PyTorch output on a random
input, otherwise the file is deleted and :class:`ModelError` raised — a silently
wrong model on a robot is worse than no model.
"""

from __future__ import annotations

import io
import os
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
from torch import nn

from ros2_mos.core.errors import ModelError

# The tensor names are the contract with the runtime: one definition, in the runtime.
from ros2_mos.core.inference import INPUT_NAME, OUTPUT_NAME  # noqa: E402
from ros2_mos.core.metadata import METADATA_KEY, TRAINING_CONFIG_KEY, ModelMetadata, save_model_atomically

DEFAULT_OPSET = 17


class ProbabilityHead(nn.Module):
    """Wrap a logits network so that the exported graph ends in a softmax over classes."""

    def __init__(self, net: nn.Module) -> None:
        super().__init__()
        self.net = net

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        logits = self.net(x)
        if logits.shape[1] != 2:
            return torch.softmax(logits, dim=1)
        # Two classes: softmax(l)_1 = sigmoid(l_1 - l_0), element-wise, no transpose (see module docstring).
        moving = torch.sigmoid(logits[:, 1:2] - logits[:, 0:1])
        return torch.cat([1.0 - moving, moving], dim=1)


@dataclass
class ExportReport:
    """What an export produced and how closely ONNX Runtime matched PyTorch."""

    path: Path
    max_abs_diff: float
    size_bytes: int


def _torch_to_onnx_bytes(wrapped: nn.Module, example: torch.Tensor, opset: int) -> bytes:
    """Run torch.onnx.export into memory; the TorchScript exporter is fast and exact for these CNNs."""
    buffer = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            wrapped,
            (example,),
            buffer,
            input_names=[INPUT_NAME],
            output_names=[OUTPUT_NAME],
            opset_version=opset,
            do_constant_folding=True,
            dynamo=False,
        )
    return buffer.getvalue()


def export_onnx(
    model: nn.Module,
    metadata: ModelMetadata,
    path: str | Path,
    *,
    opset: int = DEFAULT_OPSET,
    check: bool = True,
    atol: float = 1e-4,
    seed: int = 0,
    training_config: str | Path | None = None,
) -> ExportReport:
    """Export ``model`` (logits network) with a softmax head and ``metadata`` to ``path``.

    The input shape is (1, metadata.input.channels, sensor.height, sensor.width).
    With ``check`` the file is run in ONNX Runtime on a random normal input and
    compared with PyTorch; a max abs difference above ``atol`` raises ModelError.
    ``training_config`` (the repository path of the config that made the model; also taken from
    ``metadata.extra["training_config"]``, e.g. ``export_checkpoint(..., extra={"training_config": ...})``)
    is written as its own ``training_config`` metadata entry.
    """
    import onnx

    path = Path(path)
    if TRAINING_CONFIG_KEY in metadata.extra:
        extra = dict(metadata.extra)
        named = extra.pop(TRAINING_CONFIG_KEY)
        training_config = training_config if training_config is not None else named
        metadata = replace(metadata, extra=extra)
    if training_config is not None:
        training_config = Path(training_config).as_posix()
        if not training_config or training_config == ".":
            raise ModelError("training_config must be a non-empty path")
    channels = metadata.input.channels
    h, w = metadata.sensor.height, metadata.sensor.width
    was_training = model.training
    model.eval()
    try:
        wrapped = ProbabilityHead(model).eval()
        generator = torch.Generator().manual_seed(seed)
        example = torch.randn(1, channels, h, w, generator=generator)
        with torch.no_grad():
            try:
                reference = wrapped(example)
            except RuntimeError as exc:
                raise ModelError(
                    f"the network does not accept a (1, {channels}, {h}, {w}) input: {exc}"
                ) from None
            if reference.shape[0] != 1 or reference.shape[2:] != (h, w) or reference.shape[1] < 2:
                raise ModelError(f"the network maps (1, {channels}, {h}, {w}) to {tuple(reference.shape)}")
            raw = _torch_to_onnx_bytes(wrapped, example, opset)
    finally:
        model.train(was_training)

    proto = onnx.load_from_string(raw)
    del proto.metadata_props[:]
    entry = proto.metadata_props.add()
    entry.key = METADATA_KEY
    entry.value = metadata.to_json()
    if training_config is not None:
        named_config = proto.metadata_props.add()
        named_config.key = TRAINING_CONFIG_KEY
        named_config.value = training_config
    proto.producer_name = "ros2_mos"
    proto.doc_string = f"ros2_mos MOS model: {metadata.network}, {metadata.input.label}, {metadata.sensor.name}"
    onnx.checker.check_model(proto)

    path.parent.mkdir(parents=True, exist_ok=True)
    max_diff = 0.0

    def agrees_with_pytorch(tmp: Path) -> None:
        nonlocal max_diff
        max_diff = _check_with_onnxruntime(tmp, example.numpy(), reference.numpy())
        if not max_diff <= atol:
            raise ModelError(
                f"ONNX Runtime disagrees with PyTorch after export: max abs diff {max_diff:.3g} > {atol:.3g}"
            )

    save_model_atomically(proto, path, agrees_with_pytorch if check else None)
    return ExportReport(path=path, max_abs_diff=max_diff, size_bytes=path.stat().st_size)


def _check_with_onnxruntime(path: Path, example: np.ndarray, reference: np.ndarray) -> float:
    """Max abs difference between ONNX Runtime's and PyTorch's output on ``example``."""
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = max(1, min(2, os.cpu_count() or 1))
    session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    (out,) = session.run([OUTPUT_NAME], {INPUT_NAME: example.astype(np.float32)})
    if out.shape != reference.shape:
        raise ModelError(f"ONNX output shape {out.shape} differs from PyTorch's {reference.shape}")
    return float(np.max(np.abs(out - reference)))


def read_metadata(path: str | Path) -> ModelMetadata:
    """The ModelMetadata stored in an exported model: the runtime's own reader, re-exported for training tools."""
    from ros2_mos.core.inference import read_metadata as runtime_read_metadata

    return runtime_read_metadata(path)
