"""A perfect camera's labels: a SemanticKITTI folder's ground truth kept only
on the points camera 2 sees (P2 after Tr, in front of it, inside 1241x376;
occlusion ignored), 0 elsewhere, as `cosem label` writes them. For measuring
camera-labelled maps (`--unlabeled drop|geometry`) on pairs without images.

    python3 tests/python/camera_view_labels.py SRC DST

DST gets labels/, copies of calib.txt, poses.txt, times.txt and a link to
SRC's velodyne/. The labels are derived from SemanticKITTI (CC BY-NC-SA):
keep DST out of the repository.
"""
import numpy as np, os, sys, shutil
src, dst = sys.argv[1], sys.argv[2]
W, H = 1241, 376
os.makedirs(dst + "/labels", exist_ok=True)
cal = {}
for line in open(src + "/calib.txt"):
    k, v = line.split(":", 1)
    cal[k] = np.array([float(x) for x in v.split()])
P2 = cal["P2"].reshape(3, 4)
Tr = np.vstack([cal["Tr"].reshape(3, 4), [0, 0, 0, 1]])
for f in ["calib.txt", "poses.txt", "times.txt"]:
    shutil.copy(src + "/" + f, dst + "/" + f)
if not os.path.exists(dst + "/velodyne"):
    os.symlink(os.path.abspath(src + "/velodyne"), dst + "/velodyne")
kept = tot = 0
for name in sorted(os.listdir(src + "/velodyne")):
    pts = np.fromfile(src + "/velodyne/" + name, dtype=np.float32).reshape(-1, 4)
    lab = np.fromfile(src + "/labels/" + name[:-4] + ".label", dtype=np.uint32)
    h = np.hstack([pts[:, :3], np.ones((len(pts), 1), np.float32)]).astype(np.float64)
    c = (P2 @ (Tr @ h.T)).T
    z = c[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u, v = c[:, 0] / z, c[:, 1] / z
    seen = (z > 0.1) & (u >= 0) & (u < W) & (v >= 0) & (v < H)
    out = np.where(seen, lab, 0).astype(np.uint32)
    out.tofile(dst + "/labels/" + name[:-4] + ".label")
    kept += seen.sum(); tot += len(pts)
print(f"{dst}: {kept} of {tot} points in view ({100*kept/tot:.1f}%)")
