"""The paper's heuristic baselines (Table II) as pure functions of images: ``Residual`` and ``Residual + RG``.

* **Residual**: a pixel is moving when its newest residual |d_1| exceeds τ.  The
  paper reports how poorly this does (1.9 IoU on SemanticKITTI): residuals light up
  twice for every moving object (where it is and where it was) and on every
  occlusion edge.
* **Residual + RG** (after Yoon et al. 2019): *free-space check* + *region growing*.
  Seeds are pixels whose current point lies where both past scans saw free space
  (signed residuals (r_j − r_0) / r_0 above τ_seed for j = 1, 2: the rays passed
  farther, so something moved *in*); the "where it was" ghost fails that sign test.
  Seeds are then grown over connected non-ground regions of the range image
  (4-neighbours, range jumps below ``max(0.3 m, δ·r)``), and a region is moving when
  at least a fraction ρ of it is seeds.  Ground is removed by height (z below the
  scan's ground level + 0.3 m), as geometric pipelines do.

The training code tunes their parameters on validation caches
(:mod:`ros2_mos.training.baselines`); the evaluation suite runs them online beside a
model (:mod:`ros2_mos.scoring.suite`).  numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ros2_mos.core.segments import connected_regions, ground_mask, grow_regions


def residual_threshold(newest_residual: np.ndarray, tau: float) -> np.ndarray:
    """Residual baseline: |d_1| > τ per pixel."""
    return np.abs(newest_residual) > tau


def free_space_seeds(signed_residuals: np.ndarray, tau_seed: float) -> np.ndarray:
    """Pixels where the two newest signed residuals both exceed τ_seed (the space was free twice)."""
    return (signed_residuals[0] > tau_seed) & (signed_residuals[1] > tau_seed)


@dataclass(frozen=True)
class RegionGrowingParams:
    """Residual + RG parameters; the defaults are those tuned on the simulator's validation sequence."""

    tau_seed: float = 0.1
    rel_jump: float = 0.06
    seed_fraction: float = 0.1


def region_growing(range_image: np.ndarray, z_image: np.ndarray, signed_residuals: np.ndarray,
                   params: RegionGrowingParams = RegionGrowingParams()) -> np.ndarray:
    """Residual + RG baseline on one scan: range and z images (0 = empty) and the two newest signed residuals."""
    valid = (range_image > 0) & ~ground_mask(range_image, z_image)
    regions = connected_regions(valid, range_image, params.rel_jump)
    return grow_regions(free_space_seeds(signed_residuals, params.tau_seed), regions, params.seed_fraction)
