import json
import os
import subprocess
import sys

import numpy as np
import pytest
import trimesh

from model.octree import OctreeInputError, estimate_normals
from model.octree.__main__ import main
from model.octree.inputs import load_input

from .conftest import mesh_path, sphere_points

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def write_ply_points(path, pts, nrm=None):
    cloud = trimesh.PointCloud(pts)
    if nrm is None:
        cloud.export(path)
        return
    header = ("ply\nformat ascii 1.0\nelement vertex %d\nproperty float x\nproperty float y\n"
              "property float z\nproperty float nx\nproperty float ny\nproperty float nz\nend_header\n")
    with open(path, "w") as fh:
        fh.write(header % len(pts))
        np.savetxt(fh, np.c_[pts, nrm], fmt="%.7f")


@pytest.mark.parametrize("fmt", ["xyz", "txt", "npy", "npz", "ply"])
def test_point_clouds_with_normals_load_in_every_format(tmp_path, fmt):
    pts, nrm = sphere_points(3000)
    path = tmp_path / f"cloud.{fmt}"
    if fmt in ("xyz", "txt"):
        np.savetxt(path, np.c_[pts, nrm], delimiter="," if fmt == "txt" else " ")
    elif fmt == "npy":
        np.save(path, np.c_[pts, nrm])
    elif fmt == "npz":
        np.savez(path, points=pts, normals=nrm)
    else:
        write_ply_points(path, pts, nrm)
    loaded = load_input(str(path), 5)
    assert loaded.kind == "points" and not loaded.normals_estimated
    assert np.allclose(loaded.cloud.points, pts, atol=1e-6)
    assert np.allclose(loaded.cloud.normals, nrm, atol=1e-5)


def test_points_without_normals_get_consistent_outward_normals(tmp_path):
    pts, truth = sphere_points(20_000)
    box = trimesh.creation.box(extents=(2, 1, 0.5))
    bp, fid = trimesh.sample.sample_surface(box, 20_000, seed=1)
    for p, t in ((pts, truth), (bp, box.face_normals[fid])):
        n = estimate_normals(p)
        agree = (n * t).sum(1)
        assert np.mean(agree > 0) > 0.995       # oriented outward, not just up to sign
        assert np.mean(agree > 0.9) > 0.93      # PCA blends the faces within k points of an edge
    np.savetxt(tmp_path / "s.xyz", pts)
    loaded = load_input(str(tmp_path / "s.xyz"), 5)
    assert loaded.normals_estimated
    assert np.mean((loaded.cloud.normals * truth).sum(1) > 0.9) > 0.97


def test_meshes_are_sampled_densely_enough_for_the_depth():
    path = mesh_path("chair_soup.off")
    a = load_input(path, 5)
    b = load_input(path, 6)
    assert a.kind == "mesh" and b.sample_spacing < a.sample_spacing
    mesh = trimesh.load(path, force="mesh")
    h6 = (mesh.extents.max() / 0.96) / 64
    assert b.sample_spacing <= h6 / 3 * 1.01 or len(b.cloud) == 2_000_000
    assert len(load_input(path, 6, n_points=5000).cloud) == 5000


def _npy_bytes(arr) -> bytes:
    import io
    buf = io.BytesIO()
    np.save(buf, arr)
    return buf.getvalue()


@pytest.mark.parametrize("content,ext,msg", [
    (b"", ".obj", "empty"),
    (b"hello", ".xyz2", "unknown format"),
    (b"1 2 3\n4 5 nan\n7 8 9\n1 1 1\n", ".xyz", "NaN"),
    (b"1 2 3\n4 5 6\n", ".xyz", "at least 3"),
    (b"1 1 1\n1 1 1\n1 1 1\n1 1 1\n", ".xyz", "identical"),
    (b"0 0 0\n1 1 1\n2 2 2\n3 3 3\n", ".xyz", "on a line"),
    (b"0 0 0 0 0 0\n1 0 0 0 0 1\n0 1 0 0 0 1\n1 1 0 0 0 1\n", ".xyz", "zero length"),
    (b"1 2\n3 4\n5 6\n", ".txt", r"3 \(x y z\) or 6"),
    (b"1 2 3\n4 5\n", ".txt", "different numbers of columns"),
    (b"a b c\nd e f\ng h i\n", ".xyz", "not a number"),
    (b"\x00\x01\x02\xff\xfe" * 50, ".xyz", "binary"),
    (b"solid x\nendsolid x\n", ".stl", "empty|no triangles|cannot be read"),
    (b"v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n", ".obj", "zero area"),
    (b"garbage that is not a mesh", ".ply", "cannot be read"),
    (b"ply\nformat ascii 1.0\nelement vertex 100\nproperty float x\nproperty float y\nproperty float z\n"
     b"end_header\n0 0 0\n1 0 0\n0 1 0\n1 1 1\n", ".ply", "declares 100 vertices but the file holds 4"),
    (b"ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
     b"element face 10\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n"
     b"3 0 1 2\n3 0 1 3\n", ".ply", "declares 4 vertex and 10 face lines but the file holds 6"),
    (b"OFF\n4 10 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 2\n", ".off", "declares 4 vertex and 10 face lines"),
    (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 9\n", ".obj", "cannot be read"),
    (_npy_bytes(np.arange(12).reshape(4, 3) * (1 + 1j)), ".npy", "complex128 values, not real numbers"),
    (_npy_bytes(np.arange(12).reshape(4, 3) > 3), ".npy", "bool values, not real numbers"),
])
def test_bad_files_raise_one_clear_error(tmp_path, content, ext, msg):
    path = tmp_path / f"bad{ext}"
    path.write_bytes(content)
    with pytest.raises(OctreeInputError, match=msg):
        load_input(str(path), 5)


def test_cli_writes_mesh_and_stats_in_input_coordinates(tmp_path):
    src = mesh_path("chair_soup.off")
    out, stats = tmp_path / "chair.glb", tmp_path / "stats.json"
    assert main([src, "--depth", "6", "--out", str(out), "--stats", str(stats), "--color-by-depth"]) == 0
    s = json.loads(stats.read_text())
    for key in ("depth", "adaptive", "threshold", "nodes_per_depth", "nonempty_per_depth",
                "leaves_per_depth", "max_patch_error", "seconds"):
        assert key in s
    mesh_in = trimesh.load(src, force="mesh")
    h = mesh_in.extents.max() / 0.96 / 64
    assert s["depth"] == 6 and s["adaptive"] is True
    assert np.isclose(s["threshold"], np.sqrt(3) / 2 * h, rtol=1e-6)
    assert s["max_patch_error_above_max_depth"] <= s["threshold"]
    assert len(s["nodes_per_depth"]) == 7 and s["nodes_per_depth"][2] == 64
    assert sum(s["leaves_per_depth"]) == s["patches"]
    out_mesh = trimesh.load(out, force="mesh")
    assert np.allclose(out_mesh.bounds, mesh_in.bounds, atol=2 * h)
    full_stats = tmp_path / "full.json"
    assert main([src, "--depth", "6", "--full", "--out", str(tmp_path / "f.ply"), "--stats", str(full_stats)]) == 0
    f = json.loads(full_stats.read_text())
    assert f["adaptive"] is False and sum(f["nodes_per_depth"]) > sum(s["nodes_per_depth"])
    assert f["leaves_per_depth"][:-1] == [0] * 6


@pytest.mark.parametrize("args,msg", [
    (["missing.obj", "--depth", "5", "--out", "{tmp}/o.ply"], "no such file"),
    (["{mesh}", "--depth", "5", "--out", "{tmp}/o.xyz"], "--out must end"),
    (["{mesh}", "--depth", "0", "--out", "{tmp}/o.ply"], "--depth"),
    (["{mesh}", "--depth", "5", "--out", "{tmp}/nodir/o.ply"], "does not exist"),
    (["{mesh}", "--depth", "5", "--threshold", "-1", "--out", "{tmp}/o.ply"], "threshold"),
    (["{mesh}", "--depth", "5", "--points", "2", "--out", "{tmp}/o.ply"], "--points"),
])
def test_cli_bad_input_exits_2_with_one_line_and_writes_nothing(tmp_path, args, msg):
    mesh = mesh_path("chair_soup.off")
    argv = [a.format(tmp=tmp_path, mesh=mesh) for a in args]
    proc = subprocess.run([sys.executable, "-m", "model.octree", *argv], cwd=REPO,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and msg in lines[0] and "Traceback" not in proc.stderr
    assert list(tmp_path.iterdir()) == []


def test_cli_keeps_an_existing_output_when_the_input_is_bad(tmp_path):
    out = tmp_path / "keep.ply"
    out.write_bytes(b"previous result")
    bad = tmp_path / "bad.xyz"
    bad.write_text("1 2 3\n")
    assert main([str(bad), "--depth", "5", "--out", str(out)]) == 2
    assert out.read_bytes() == b"previous result"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.xyz", "keep.ply"]


def _half_sphere(n: int = 4000) -> tuple[np.ndarray, np.ndarray]:
    pts, nrm = sphere_points(n)
    keep = pts[:, 0] > 0                    # a partial scan: the side the scanner saw
    return pts[keep], nrm[keep]


@pytest.mark.parametrize("where,count,dropped", [
    (1000.0, 50, 50),          # a second thing metres away: dropped
    (5.0, 1, 1),               # one flying pixel beyond the empty shell
    (2.0, 1, 0),               # 2 radii out: inside 3 times the rest's radius, kept
    (1000.0, 400, 0),          # a fifth of the cloud: two objects, not strays; kept
])
def test_points_far_from_the_rest_are_dropped_and_counted(where, count, dropped):
    from model.octree.pointcloud import validate

    pts, nrm = _half_sphere()
    far = pts[:count] + [where, 0.0, 0.0]
    cloud = validate(np.r_[pts, far], np.r_[nrm, nrm[:count]])
    assert cloud.strays == dropped and len(cloud) == len(pts) + count - dropped
    if dropped:
        assert np.array_equal(cloud.points, pts) and np.allclose(cloud.normals, nrm)
    assert validate(pts, None).strays == 0


def test_a_clean_cloud_loses_no_point_and_a_cluster_with_strays_is_no_line():
    from model.octree.pointcloud import validate

    pts, nrm = _half_sphere()
    thin = np.c_[np.linspace(0, 1, 500), np.zeros(500), np.zeros(500)]
    assert validate(np.r_[pts * 0.01, pts + [30, 0, 0]], None).strays == 0     # two halves: both kept
    with pytest.raises(OctreeInputError, match="identical within rounding"):
        validate(np.r_[np.ones((200, 3)), [[50.0, 0, 0]]], None)               # one spot and a stray
    with pytest.raises(OctreeInputError, match="on a line"):
        validate(np.r_[thin, [[0, 300.0, 0]]], None)


def test_cli_says_how_many_points_far_from_the_rest_it_dropped(tmp_path, capsys):
    pts, nrm = _half_sphere()
    src = tmp_path / "scan.npy"
    np.save(src, np.c_[np.r_[pts, pts[:20] + 500.0], np.r_[nrm, nrm[:20]]])
    stats = tmp_path / "s.json"
    assert main([str(src), "--depth", "5", "--out", str(tmp_path / "o.ply"), "--stats", str(stats)]) == 0
    assert "20 point(s) far from the rest dropped" in capsys.readouterr().out
    s = json.loads(stats.read_text())
    assert s["points_dropped"] == 20 and s["points"] == len(pts)
    out = trimesh.load(tmp_path / "o.ply", force="mesh")
    assert out.bounds[1].max() < 1.2               # the half sphere's own frame, not one 500 units wide


def test_a_mesh_keeps_a_small_part_far_from_the_rest(tmp_path):
    """A mesh's samples are its geometry: a small box far from a large one is kept, not dropped."""
    big = trimesh.creation.box((1.0, 1.0, 1.0))
    small = trimesh.creation.box((0.05, 0.05, 0.05))
    small.apply_translation((20.0, 0.0, 0.0))
    path = tmp_path / "two.ply"
    trimesh.util.concatenate([big, small]).export(path)
    loaded = load_input(str(path), 5)
    assert loaded.kind == "mesh" and loaded.cloud.strays == 0
    assert loaded.cloud.points[:, 0].max() > 19.9


@pytest.mark.parametrize("header,sep,newline,bom", [
    ("x y z", " ", "\n", False),
    ("X,Y,Z,Nx,Ny,Nz", ",", "\r\n", True),          # a spreadsheet's CSV: byte-order mark, CRLF
    ("//X,Y,Z,Nx,Ny,Nz", ",", "\n", False),          # CloudCompare's comment header
    ("", " ", "\n", True),                           # no header, a byte-order mark
])
def test_text_point_lists_with_a_header_line_of_column_names(tmp_path, header, sep, newline, bom):
    from model.formats import identify

    pts, nrm = sphere_points(300)
    cols = np.c_[pts, nrm] if header.count(",") == 5 else pts
    body = newline.join(sep.join(f"{v:.6f}" for v in row) for row in cols)
    text = (header + newline if header else "") + body + newline
    data = (b"\xef\xbb\xbf" if bom else b"") + text.encode()
    assert identify(data).loader == "xyz"
    for name in ("scan.csv", "scan.txt"):
        path = tmp_path / name
        path.write_bytes(data)
        loaded = load_input(str(path), 5)
        assert len(loaded.cloud) == 300 and np.allclose(loaded.cloud.points, pts, atol=1e-6)
        assert loaded.normals_estimated == (cols.shape[1] == 3)


@pytest.mark.parametrize("first", ["nan nan nan", "x y", "x y 3"])
def test_what_is_not_a_header_line_stays_data(first):
    from model.formats import is_column_header

    assert not is_column_header(first)


def test_stray_points_match_their_definition_on_random_clouds():
    """All radii sorted, the first gap of more than STRAY_GAP among the farthest tenth: the rule
    written plainly, against the function's partial sort."""
    from model.octree.pointcloud import STRAY_GAP, STRAY_SHARE, stray_points

    rng = np.random.default_rng(7)
    dropped = 0
    for trial in range(200):
        n = int(rng.integers(3, 3000))
        p = rng.normal(size=(n, 3))
        k = int(rng.integers(0, n // 8 + 1))
        p[:k] += rng.normal(size=3) * rng.uniform(0, 50)         # a cluster, near or far
        r = np.linalg.norm(p - np.median(p, axis=0), axis=1)
        order = np.argsort(r)
        first = max(int(np.ceil((1 - STRAY_SHARE) * n)) - 1, 0)
        want = np.zeros(n, bool)
        for i in range(first, n - 1):
            if r[order[i + 1]] > STRAY_GAP * r[order[i]]:
                want[order[i + 1:]] = True
                break
        got = stray_points(p)
        assert np.array_equal(got, want), trial
        dropped += int(got.any())
    assert 20 < dropped < 180                                   # both outcomes were exercised
