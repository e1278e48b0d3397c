"""Time PointCloud2 <-> numpy on a 120k-point cloud: `python benchmarks/bench_pointcloud2.py`."""
import sys
import time

import numpy as np
from sensor_msgs.msg import PointCloud2, PointField

from ros2_mos.core.memory import retain_freed_memory
from ros2_mos.io.pointcloud2 import decode_xyz_intensity, fill_subset, fill_with_extra_fields, fill_xyzi

if "--no-malloc-tuning" not in sys.argv:
    retain_freed_memory()  # as the node does (tune_malloc)
rng=np.random.default_rng(0)
n=120_000
pts=rng.normal(scale=20,size=(n,3)).astype(np.float32)
pts[::50]=np.nan
inten=rng.random(n).astype(np.float32)
def t(f, reps=50):
    f()
    s=time.perf_counter()
    for _ in range(reps):
        f()
    return (time.perf_counter()-s)/reps*1e3
msg=fill_xyzi(PointCloud2(), pts, inten, field_factory=PointField)
p,i,v=decode_xyz_intensity(msg)
idx=v[::2]
lab=np.ones(len(v),np.uint8)
pr=np.ones(len(v),np.float32)
print(f"encode xyzi 120k: {t(lambda: fill_xyzi(PointCloud2(), pts, inten, field_factory=PointField)):.2f} ms")
print(f"decode 120k (2% NaN): {t(lambda: decode_xyz_intensity(msg)):.2f} ms")
print(f"subset 60k: {t(lambda: fill_subset(PointCloud2(), msg, idx, field_factory=PointField)):.2f} ms")
def labels():
    return fill_with_extra_fields(PointCloud2(), msg, v, [('moving',lab),('moving_probability',pr)],
                                  field_factory=PointField)
print(f"labels 118k (+moving,+prob): {t(labels):.2f} ms")
