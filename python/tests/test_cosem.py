"""pytest for the Python bindings: maps from points, files, and matching
two maps of a synthetic street corner with a known transform."""

import math

import numpy as np
import pytest

import cosem

ROAD, SIDEWALK, BUILDING, POLE, VEGETATION, CAR = 40, 48, 50, 80, 70, 10


def corner(rng):
    """Labelled points of a street corner: road, sidewalk, two walls, poles,
    a tree and parked cars, irregularly placed (no symmetry)."""
    pts, labels = [], []

    def add(p, label):
        pts.append(p)
        labels.append(np.full(len(p), label))

    g = np.mgrid[-30:30:0.2, -20:20:0.2].reshape(2, -1).T
    ground = np.column_stack([g, np.full(len(g), -1.7)])
    add(ground[np.abs(ground[:, 1]) < 6], ROAD)
    add(ground[np.abs(ground[:, 1]) >= 6], SIDEWALK)
    w = np.mgrid[-30:12:0.2, -1.7:6:0.2].reshape(2, -1).T
    add(np.column_stack([w[:, 0], np.full(len(w), 11.0), w[:, 1]]), BUILDING)
    w = np.mgrid[-20:15:0.2, -1.7:4:0.2].reshape(2, -1).T
    add(np.column_stack([np.full(len(w), 14.0), w[:, 0], w[:, 1]]), BUILDING)
    for x, y in [(-22.0, -7.0), (-9.5, 7.5), (3.0, -7.5), (9.0, 8.0)]:
        z = np.arange(-1.7, 4.0, 0.1)
        add(np.column_stack([np.full(len(z), x), np.full(len(z), y), z]), POLE)
    a = rng.uniform(0, 2 * math.pi, 800)
    h = rng.uniform(1.0, 4.5, 800)
    add(np.column_stack([-4.0 + 1.6 * np.cos(a), 8.5 + 1.6 * np.sin(a), h]), VEGETATION)
    for x, y in [(-15.0, 4.0), (-2.0, -4.5), (6.0, 4.0)]:
        c = np.mgrid[-2:2:0.2, -0.9:0.9:0.2, -1.6:-0.3:0.2].reshape(3, -1).T
        add(c + np.array([x, y, 0.0]), CAR)
    p = np.vstack(pts)
    return p + rng.normal(0.0, 0.01, p.shape), np.concatenate(labels)


def rot_z(deg, t):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    m = np.eye(4)
    m[:2, :2] = [[c, -s], [s, c]]
    m[:3, 3] = t
    return m


def errors(a, b):
    d = np.linalg.inv(a) @ b
    angle = math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(d[:3, :3]) - 1) / 2))))
    return np.linalg.norm(d[:3, 3]), angle


@pytest.fixture(scope="module")
def maps():
    rng = np.random.default_rng(7)
    p, labels = corner(rng)
    truth = rot_z(35.0, [4.0, -2.5, 0.0])  # T_model_scene
    q, qlabels = corner(np.random.default_rng(8))
    scene_points = (np.linalg.inv(truth) @ np.column_stack([q, np.ones(len(q))]).T).T[:, :3]
    model = cosem.Map.from_points(p, labels, 0.5)
    scene = cosem.Map.from_points(scene_points, qlabels, 0.5)
    return model, scene, truth


def test_maps_from_points_hold_their_classes_and_round_trip(tmp_path, maps):
    model, _, _ = maps
    assert len(model) > 2000 and model.resolution == 0.5
    pos, classes = model.voxels()
    assert pos.shape == (len(model), 3) and pos.dtype == np.float32
    names = {cosem.CLASSES[c] for c in classes if c != 255}
    assert names == {"road", "sidewalk", "building", "pole", "vegetation", "car"}
    path = tmp_path / "m.cmap"
    model.save(str(path))
    back = cosem.Map.load(str(path))
    assert len(back) == len(model)
    # The file holds the voxels in another order, each class kept.
    assert np.array_equal(np.bincount(back.voxels()[1], minlength=256), np.bincount(classes, minlength=256))
    # ... and each position to the encoding's quarter voxel (within its cell).
    key = lambda p: np.floor(p / 0.5).astype(np.int64)
    a = {tuple(k): v for k, v in zip(key(pos), pos)}
    for k, v in zip(key(back.voxels()[0]), back.voxels()[0]):
        assert np.abs(a[tuple(k)] - v).max() <= 0.5 / 8 + 1e-4


def test_match_without_a_prior_and_from_one(maps):
    model, scene, truth = maps
    r = cosem.match(model, scene)
    assert r.status == "Converged"
    e_t, e_r = errors(r.transform, truth)
    assert e_t < 0.1 and e_r < 0.5, (e_t, e_r)
    assert r.transform.shape == (4, 4) and r.information.shape == (6, 6)
    assert 0.5 < r.overlap <= 1.0 and r.inliers > 100
    start = truth @ rot_z(5.0, [1.0, -1.0, 0.0])
    r2 = cosem.match(model, scene, init=start)
    assert r2.status == "Converged"
    e_t, e_r = errors(r2.transform, truth)
    assert e_t < 0.1 and e_r < 0.5, (e_t, e_r)


def test_match_settings_go_through_the_pipeline_validator(maps):
    model, scene, truth = maps
    geo = cosem.match(model, scene, method="geometric", dof=4)
    assert geo.status == "Converged"
    assert errors(geo.transform, truth)[0] < 0.2
    # Each setting reaches the matcher: a search stopped at once finds no
    # placement, EM stops at its iterations, and the verdict's thresholds
    # turn the same pair down when set above what it has.
    assert cosem.match(model, scene, search_nodes=1).status == "NoOverlap"
    start = truth @ rot_z(5.0, [1.0, -1.0, 0.0])
    assert cosem.match(model, scene, init=start).iterations > 2
    assert cosem.match(model, scene, init=start, em_iterations=2).iterations <= 2
    r = cosem.match(model, scene)
    assert r.agreement < 1.0 or r.overlap < 1.0, r
    strict = dict(min_agreement=1.0) if r.agreement < 1.0 else dict(min_overlap=1.0)
    assert cosem.match(model, scene, **strict).status == "NoOverlap", (r, strict)
    for bad in [dict(method="icp"), dict(dof=5), dict(em_iterations=0), dict(em_iterations=2.5),
                dict(min_overlap=1.5), dict(min_agreement=float("nan")), dict(search_nodes=-1)]:
        with pytest.raises(ValueError) as e:
            cosem.match(model, scene, **bad)
        name = next(iter(bad))
        shown = {"em_iterations": "EM iterations", "min_overlap": "least overlap", "min_agreement": "least agreement",
                 "search_nodes": "search nodes"}.get(name, name)
        assert shown in str(e.value), (bad, str(e.value))


def test_bad_input_is_a_python_error(tmp_path, maps):
    model, scene, _ = maps
    with pytest.raises(ValueError):
        cosem.Map.from_points(np.zeros((5, 2)), np.zeros(5, dtype=np.int64), 0.5)
    with pytest.raises(ValueError):
        cosem.Map.from_points(np.zeros((5, 3)), np.zeros(4, dtype=np.int64), 0.5)
    with pytest.raises(ValueError):
        cosem.Map.from_points(np.full((1, 3), np.nan), np.array([40]), 0.5)
    with pytest.raises(ValueError):
        cosem.match(model, scene, init=np.eye(3))
    with pytest.raises(OSError):
        cosem.Map.load(str(tmp_path / "missing.cmap"))
    other = cosem.Map.from_points(np.zeros((1, 3)), np.array([40]), 0.2)
    with pytest.raises(ValueError):
        cosem.match(model, other)


def test_any_number_dtype_is_taken_and_other_input_named(maps):
    model, _, _ = maps
    p, labels = corner(np.random.default_rng(7))
    want = cosem.Map.from_points(p, labels, 0.5)
    for xyz in (p.astype(np.float32), p.tolist()):
        for lab in (labels.astype(np.uint16), labels.astype(np.int32), labels.astype(np.uint64), labels.tolist()):
            got = cosem.Map.from_points(xyz, lab, 0.5)
            # float32 coordinates may move a point across a voxel face.
            assert abs(len(got) - len(want)) <= len(want) // 1000
    # Instance ids above the low 16 bits keep the class; 2**32 + 40 is road.
    big = labels.astype(np.uint64) + (np.uint64(7) << np.uint64(32))
    assert len(cosem.Map.from_points(p, big, 0.5)) == len(want)
    with pytest.raises(ValueError, match="never negative"):
        cosem.Map.from_points(p[:3], np.array([40, -40, 50]), 0.5)
    with pytest.raises(ValueError, match="integer"):
        cosem.Map.from_points(p[:3], np.array([40.0, 40.0, 50.0]), 0.5)
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        cosem.Map.from_points(np.array(["a", "b", "c"]), np.array([40, 40, 50]), 0.5)
    with pytest.raises(ValueError, match="empty"):
        cosem.Map.from_points(p[:3], np.array([1000, 1000, 1000]), 0.5)
    # One voxel range, as the command line's: a robot's map is 0.02 to 10 m.
    for voxel in (0.01, 11.0):
        with pytest.raises(ValueError, match="0.02 to 10 m"):
            cosem.Map.from_points(p[:3], np.array([40, 40, 50]), voxel)


def test_voxels_round_trip_through_from_voxels(maps):
    model, _, _ = maps
    pos, classes = model.voxels()
    back = cosem.Map.from_voxels(pos, classes, model.resolution)
    assert len(back) == len(model)
    p2, c2 = back.voxels()
    order = lambda p: np.lexsort(np.floor(p / 0.5).T)
    assert np.array_equal(classes[order(pos)], c2[order(p2)])
    assert np.allclose(pos[order(pos)], p2[order(p2)], atol=1e-5)
    with pytest.raises(ValueError, match="class index"):
        cosem.Map.from_voxels(pos[:2], np.array([0, 40]), 0.5)
    with pytest.raises(ValueError, match="class index"):
        cosem.Map.from_voxels(pos[:1], np.array([254]), 0.5)
    # Empty arrays are no map: refused, never a 0-voxel map to save.
    with pytest.raises(ValueError, match="empty"):
        cosem.Map.from_voxels(np.zeros((0, 3)), np.zeros(0, dtype=np.uint8), 0.5)


def test_unlabelled_points_kept_as_geometry_when_asked(tmp_path, maps):
    rng = np.random.default_rng(7)
    p, labels = corner(rng)
    # A camera sees the half x < 0: the rest is unlabelled (id 0).
    seen = np.where(p[:, 0] < 0.0, labels, 0)
    dropped = cosem.Map.from_points(p, seen, 0.5)
    kept = cosem.Map.from_points(p, seen, 0.5, unlabeled="geometry")
    classes = kept.voxels()[1]
    unknown = int((classes == 255).sum())
    assert len(kept) > len(dropped) + 500 and unknown > 500
    assert not (dropped.voxels()[1] == 255).any()
    # Unknown voxels survive the round trips through a file and from_voxels.
    back = cosem.Map.from_voxels(*kept.voxels(), kept.resolution)
    assert int((back.voxels()[1] == 255).sum()) == unknown
    kept.save(str(tmp_path / "k.cmap"))
    assert int((cosem.Map.load(str(tmp_path / "k.cmap")).voxels()[1] == 255).sum()) == unknown
    # Such maps still match: the scene of the fixture against this model.
    _, scene, truth = maps
    r = cosem.match(kept, scene, init=truth @ rot_z(5.0, [1.0, -1.0, 0.0]))
    t, a = errors(r.transform, truth)
    assert r.status == "Converged" and t < 0.3 and a < 1.0, (r, t, a)
    with pytest.raises(ValueError, match="geometry"):
        cosem.Map.from_points(p, seen, 0.5, unlabeled="keep")


def test_init_of_any_float_dtype_or_a_list(maps):
    model, scene, truth = maps
    start = truth @ rot_z(5.0, [1.0, -1.0, 0.0])
    for init in (start.astype(np.float32), start.tolist()):
        r = cosem.match(model, scene, init=init)
        assert r.status == "Converged"
    with pytest.raises(ValueError, match="4x4"):
        cosem.match(model, scene, init=np.eye(3).tolist())
    with pytest.raises(ValueError, match="4x4"):
        cosem.match(model, scene, init=np.array(["a"] * 16).reshape(4, 4))
