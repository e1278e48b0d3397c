"""Import the networks the LiDAR-MOS authors released (Chen et al., RA-L 2021) as this project's ONNX models.

The released folders (``model_salsanext_residual_1``, ``model_salsanext_residual_8``,
``model_rangenet_residual_1``) hold ``arch_cfg.yaml``, ``data_cfg.yaml`` and

* SalsaNext: ``SalsaNext_valid_best``, a ``torch.save`` dict (``epoch``, ``state_dict``,
  ``optimizer``, ``info``, ``scheduler``) whose state dict was saved through
  ``nn.DataParallel`` (keys may carry a ``module.`` prefix) and which pickles a
  learning-rate scheduler object of the authors' code;
* RangeNet++: three plain state dicts, ``backbone``, ``segmentation_decoder`` and
  ``segmentation_head``.

Loading executes no pickled code: :func:`safe_load` unpickles with an allow-list
(torch's tensor rebuilders, ``OrderedDict`` and plain builtins); any other global
(the scheduler, numpy scalars in ``info``) becomes an inert stub that is never called
into, and nothing of it is used.  The weights then go into this project's
:mod:`~ros2_mos.training.nets.salsanext` / :mod:`~ros2_mos.training.nets.rangenet`,
which carry the published parameter names, with a strict load: a wrong N, missing or
extra keys are one-line errors.

The networks end in 3 classes (0 unlabeled, 1 static, 2 moving; LiDAR-MOS applies its
softmax inside SalsaNext).  The export feeds the runtime's two-class convention with
exactly one softmax: logits ``[0, l_2 - logsumexp(l_0, l_1)]``, whose two-class softmax
is ``softmax(l)_2``, the official moving probability.

Input (LiDAR-MOS's parser): ``[range, x, y, z, remission]`` normalised with
``img_means``/``img_stds`` of ``arch_cfg.yaml``, then the N residual images
``|r - r_j| / r`` unnormalised, every channel times the projection mask; that is this
project's ``InputSetup("residual", N)`` with the file's normalisation, so the
pipeline builds it unchanged.
"""

from __future__ import annotations

import io
import pickle
import types
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import torch
from torch import nn

from ros2_mos.core.config import SENSOR_PRESETS, SensorConfig
from ros2_mos.core.errors import ModelError
from ros2_mos.core.metadata import ModelMetadata
from ros2_mos.core.network_input import InputSetup

SALSANEXT_FILE = "SalsaNext_valid_best"
RANGENET_FILES = ("backbone", "segmentation_decoder", "segmentation_head")
MOVING_CLASS = 2  # LiDAR-MOS's learning map: 0 unlabeled, 1 static, 2 moving

_ALLOWED_GLOBALS = {
    ("collections", "OrderedDict"),
    ("torch._utils", "_rebuild_tensor"),
    ("torch._utils", "_rebuild_tensor_v2"),
    ("torch._utils", "_rebuild_parameter"),
    ("torch._utils", "_rebuild_parameter_with_state"),
    ("torch", "Size"),
    ("builtins", "set"),
    ("builtins", "frozenset"),
    ("builtins", "slice"),
    ("builtins", "complex"),
}


class _Stub:
    """Stands in for any class or function the allow-list does not name: it accepts anything, runs nothing."""

    _stub_name = "?"

    def __new__(cls, *args: Any, **kwargs: Any) -> "_Stub":
        return object.__new__(cls)

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        pass

    def __setstate__(self, state: Any) -> None:
        object.__setattr__(self, "_stub_state", state)

    def __repr__(self) -> str:
        return f"<stub of {self._stub_name}>"


class _SafeUnpickler(pickle.Unpickler):
    def find_class(self, module: str, name: str) -> Any:
        if (module, name) in _ALLOWED_GLOBALS:
            return super().find_class(module, name)
        return type(name, (_Stub,), {"_stub_name": f"{module}.{name}"})


def _safe_pickle_module() -> types.ModuleType:
    module = types.ModuleType("ros2_mos_safe_pickle")
    module.Unpickler = _SafeUnpickler  # type: ignore[attr-defined]
    module.load = lambda f, **kw: _SafeUnpickler(f, **kw).load()  # type: ignore[attr-defined]
    module.loads = lambda b, **kw: _SafeUnpickler(io.BytesIO(b), **kw).load()  # type: ignore[attr-defined]
    module.__dict__["UnpicklingError"] = pickle.UnpicklingError
    return module


def safe_load(path: str | Path) -> Any:
    """``torch.load`` of a checkpoint that calls no pickled code (allow-list plus inert stubs)."""
    path = Path(path)
    if not path.is_file():
        raise ModelError(f"checkpoint not found: {path}")
    try:
        return torch.load(path, map_location="cpu", pickle_module=_safe_pickle_module(), weights_only=False)
    except Exception as exc:  # truncated zip, random bytes, ...: torch raises many types
        raise ModelError(f"{path} is not a readable PyTorch checkpoint ({type(exc).__name__}: "
                         f"{str(exc).splitlines()[0] if str(exc) else ''})") from None


@dataclass
class ArchConfig:
    """What the import needs from LiDAR-MOS's ``arch_cfg.yaml``."""

    n_residual: int
    means: tuple[float, ...]
    stds: tuple[float, ...]
    sensor: SensorConfig
    layers: int | None  # RangeNet++ Darknet depth, when given

    @classmethod
    def read(cls, path: Path) -> "ArchConfig":
        import yaml

        if not path.is_file():
            raise ModelError(f"{path.parent}: no arch_cfg.yaml (expected a LiDAR-MOS model folder)")
        try:
            arch = yaml.safe_load(path.read_text(encoding="utf-8"))
            sensor = arch["dataset"]["sensor"]
            n = int(sensor.get("n_input_scans", 0)) if sensor.get("residual", False) else 0
            means = tuple(float(v) for v in sensor["img_means"])
            stds = tuple(float(v) for v in sensor["img_stds"])
            h, w = int(sensor["img_prop"]["height"]), int(sensor["img_prop"]["width"])
            up, down = float(sensor["fov_up"]), float(sensor["fov_down"])
            layers = (arch.get("backbone") or {}).get("extra", {}).get("layers")
        except (yaml.YAMLError, UnicodeDecodeError, KeyError, TypeError, ValueError, AttributeError) as exc:
            raise ModelError(f"{path}: not a LiDAR-MOS arch config ({type(exc).__name__}: {exc})") from None
        if len(means) != 5 or len(stds) != 5 or min(stds) <= 0:
            raise ModelError(f"{path}: img_means/img_stds must be 5 values (r, x, y, z, e), stds > 0")
        if not 0 <= n <= 32:
            raise ModelError(f"{path}: n_input_scans {n} is outside 0..32")
        hdl64 = SENSOR_PRESETS["hdl64"]
        same = (h, w, up, down) == (hdl64.height, hdl64.width, hdl64.fov_up_deg, hdl64.fov_down_deg)
        sensor_cfg = hdl64 if same else SensorConfig("lidar-mos", h, w, up, down, 0.0, hdl64.max_range)
        return cls(n, means, stds, sensor_cfg, int(layers) if layers else None)


class MovingOfThree(nn.Module):
    """Two-class logits ``[0, l_2 - logsumexp(l_0, l_1)]`` of a 3-class network: their softmax is softmax(l)_2."""

    def __init__(self, net: nn.Module) -> None:
        super().__init__()
        self.net = net

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        logits = self.net(x)
        moving = logits[:, MOVING_CLASS : MOVING_CLASS + 1] - torch.logsumexp(logits[:, :MOVING_CLASS], dim=1,
                                                                               keepdim=True)
        return torch.cat([torch.zeros_like(moving), moving], dim=1)


def _strict_load(net: nn.Module, state: Mapping[str, Any], what: str, n_residual: int) -> None:
    expected = net.state_dict()
    missing = sorted(set(expected) - set(state))
    extra = sorted(set(state) - set(expected))
    if missing or extra:
        raise ModelError(f"{what}: the weights do not fit the published layout ({len(missing)} missing, e.g. "
                         f"{missing[:3]}; {len(extra)} unexpected, e.g. {extra[:3]})")
    for key, value in state.items():
        if not isinstance(value, torch.Tensor):
            raise ModelError(f"{what}: {key} is not a tensor")
        if tuple(value.shape) != tuple(expected[key].shape):
            if value.ndim == 4 and expected[key].ndim == 4 and value.shape[0] == expected[key].shape[0] \
                    and value.shape[1] != expected[key].shape[1]:
                raise ModelError(f"{what}: {key} takes {value.shape[1]} input channels, but arch_cfg.yaml says "
                                 f"N={n_residual} residual images ({5 + n_residual} channels): wrong N or arch_cfg")
            raise ModelError(f"{what}: {key} has shape {tuple(value.shape)}, the layout needs "
                             f"{tuple(expected[key].shape)}")
    net.load_state_dict(state, strict=True)


def _salsanext(folder: Path, arch: ArchConfig) -> nn.Module:
    from ros2_mos.training.nets import build_network

    ckpt = safe_load(folder / SALSANEXT_FILE)
    if not isinstance(ckpt, Mapping) or not isinstance(ckpt.get("state_dict"), Mapping):
        raise ModelError(f"{folder / SALSANEXT_FILE}: expected a dict with a 'state_dict' (LiDAR-MOS layout)")
    state = {(k[len("module."):] if k.startswith("module.") else k): v for k, v in ckpt["state_dict"].items()}
    net = build_network("salsanext", 5 + arch.n_residual, 3)
    _strict_load(net, state, f"{folder / SALSANEXT_FILE}", arch.n_residual)
    return net


def _rangenet(folder: Path, arch: ArchConfig) -> tuple[nn.Module, str]:
    from ros2_mos.training.nets import build_network

    parts = {}
    for name in RANGENET_FILES:
        part = safe_load(folder / name)
        if not isinstance(part, Mapping):
            raise ModelError(f"{folder / name}: expected a state dict")
        parts[name] = part
    layers = arch.layers or (53 if "enc3.residual_7.conv1.weight" in parts["backbone"] else 21)
    if layers not in (21, 53):
        raise ModelError(f"{folder}: Darknet-{layers} is not a RangeNet++ backbone (21 or 53)")
    state = {f"backbone.{k}": v for k, v in parts["backbone"].items()}
    state.update({f"decoder.{k}": v for k, v in parts["segmentation_decoder"].items()})
    state.update({f"head.{k}": v for k, v in parts["segmentation_head"].items()})
    name = f"rangenet{layers}"
    net = build_network(name, 5 + arch.n_residual, 3)
    _strict_load(net, state, str(folder), arch.n_residual)
    return net, name


def import_lidar_mos(folder: str | Path, out: str | Path):
    """Export a released LiDAR-MOS model folder (SalsaNext or RangeNet++) to this project's ONNX model."""
    from ros2_mos.training.export import export_onnx

    folder = Path(folder)
    if not folder.is_dir():
        raise ModelError(f"model folder not found: {folder}")
    arch = ArchConfig.read(folder / "arch_cfg.yaml")
    if (folder / SALSANEXT_FILE).is_file():
        net, name = _salsanext(folder, arch), "salsanext"
    elif all((folder / f).is_file() for f in RANGENET_FILES):
        net, name = _rangenet(folder, arch)
    else:
        raise ModelError(f"{folder}: neither {SALSANEXT_FILE} (SalsaNext) nor {', '.join(RANGENET_FILES)} "
                         "(RangeNet++) found: an unknown layout")
    meta = ModelMetadata(
        network=name,
        input=InputSetup("residual", arch.n_residual),
        sensor=arch.sensor,
        means=arch.means,
        stds=arch.stds,
        trained_on=f"LiDAR-MOS release {folder.name} (SemanticKITTI, Velodyne HDL-64E)",
        extra={"source": "PRBonn/LiDAR-MOS", "classes": "moving = LiDAR-MOS class 2 (softmax over 3)",
               "recommended_threshold": 0.5},
    )
    return export_onnx(MovingOfThree(net.eval()), meta, out)
