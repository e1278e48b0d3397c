"""SalsaNext's loss for MOS: weighted cross-entropy + Lovász-Softmax.

Moving points are rare (~0.3% on SemanticKITTI), so plain cross-entropy would learn
"everything static".  As in SalsaNext / LiDAR-MOS the cross-entropy is weighted by
the inverse class frequency, ``w_c = 1 / (f_c + eps)`` (static ≈ 1, moving ≈ 250-300
there), and the Lovász-Softmax term (Berman et al. 2018) optimises the IoU itself.
Ignored pixels (label -1: unlabeled, outliers, empty pixels) count in neither term.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from ros2_mos.core.errors import ConfigError
from ros2_mos.io.labels import IGNORE


def inverse_frequency_weights(
    counts: Sequence[int] | np.ndarray, eps: float = 1e-3, ignore: Sequence[int] = ()
) -> np.ndarray:
    """``1 / (frequency + eps)`` per class from label counts; classes in ``ignore`` get weight 0."""
    counts = np.asarray(counts, dtype=np.float64)
    total = counts.sum()
    if total <= 0:
        raise ConfigError("class counts are all zero: no labelled pixel to weight the loss with")
    weights = 1.0 / (counts / total + eps)
    for c in ignore:
        weights[c] = 0.0
    return weights.astype(np.float32)


def lovasz_grad(gt_sorted: torch.Tensor) -> torch.Tensor:
    """Gradient of the Lovász extension of the Jaccard loss w.r.t. sorted errors (Berman et al., Alg. 1)."""
    p = len(gt_sorted)
    gts = gt_sorted.sum()
    intersection = gts - gt_sorted.cumsum(0)
    union = gts + (1.0 - gt_sorted).cumsum(0)
    jaccard = 1.0 - intersection / union
    if p > 1:
        jaccard[1:p] = jaccard[1:p] - jaccard[0:-1]
    return jaccard


def lovasz_softmax_flat(probas: torch.Tensor, labels: torch.Tensor, classes: str = "present") -> torch.Tensor:
    """Lovász-Softmax over (P, C) probabilities and (P,) labels already stripped of ignored entries."""
    if probas.numel() == 0:
        return probas.sum() * 0.0
    n_classes = probas.shape[1]
    losses = []
    for c in range(n_classes):
        fg = (labels == c).to(probas.dtype)
        if classes == "present" and fg.sum() == 0:
            continue
        errors = (fg - probas[:, c]).abs()
        errors_sorted, perm = torch.sort(errors, 0, descending=True)
        losses.append(torch.dot(errors_sorted, lovasz_grad(fg[perm])))
    if not losses:
        return probas.sum() * 0.0
    return torch.stack(losses).mean()


def lovasz_softmax(
    probas: torch.Tensor, labels: torch.Tensor, ignore: int = IGNORE, classes: str = "present"
) -> torch.Tensor:
    """Lovász-Softmax of (B, C, H, W) probabilities against (B, H, W) labels, over the whole batch."""
    c = probas.shape[1]
    flat_p = probas.permute(0, 2, 3, 1).reshape(-1, c)
    flat_l = labels.reshape(-1)
    keep = flat_l != ignore
    return lovasz_softmax_flat(flat_p[keep], flat_l[keep], classes)


class MosLoss(nn.Module):
    """``wCE + lovasz_weight * Lovász-Softmax`` on logits; returns (total, ce, lovasz)."""

    def __init__(
        self, class_weights: Sequence[float] | np.ndarray, lovasz_weight: float = 1.0, ignore: int = IGNORE
    ) -> None:
        super().__init__()
        self.register_buffer("weight", torch.as_tensor(np.asarray(class_weights, np.float32)))
        self.lovasz_weight = float(lovasz_weight)
        self.ignore = ignore

    def forward(self, logits: torch.Tensor, labels: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        labels = labels.long()
        if (labels != self.ignore).sum() == 0:
            zero = logits.sum() * 0.0
            return zero, zero, zero
        ce = F.cross_entropy(logits, labels, weight=self.weight, ignore_index=self.ignore)
        lov = (
            lovasz_softmax(torch.softmax(logits, dim=1), labels, self.ignore)
            if self.lovasz_weight
            else logits.sum() * 0.0
        )
        return ce + self.lovasz_weight * lov, ce, lov
