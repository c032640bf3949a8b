"""Every endpoint over HTTP (TestClient): outputs, headers, formats, and the models they come from."""

from __future__ import annotations

import io
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image

from export.bundle import load_bundle
from export.runtime import Runtime
from model.files import sha256_file
from model.surface import surface_mesh

from .conftest import make_client

REPO = Path(__file__).resolve().parents[2]


def png(img: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(img).save(buf, format="PNG")
    return buf.getvalue()


def photo(seed: int = 0) -> bytes:
    rng = np.random.default_rng(seed)
    img = rng.integers(170, 255, (100, 140, 3)).astype(np.uint8)
    img[25:80, 40:100] = (60, 80, 120)
    return png(img)


def partial_cloud(clouds, shift=(100.0, -20.0, 5.0), scale=40.0) -> np.ndarray:
    pts = clouds[-1][0]
    keep = pts[:, 0] < np.quantile(pts[:, 0], 0.7)
    return pts[keep] * scale + np.asarray(shift)


def test_health_readiness_and_their_v2_aliases(client):
    for path in ("/healthz", "/v2/health/live"):
        assert client.get(path).json() == {"status": "ok"}
    for path in ("/readyz", "/v2/health/ready"):
        r = client.get(path)
        assert r.status_code == 200 and r.json() == {"ready": True,
                                                      "models": ["classify", "completion", "image-to-shape"]}


def test_models_lists_each_bundle_with_the_checksums_of_its_files(client, models_dir):
    body = client.get("/v1/models").json()
    tasks = {m["task"]: m for m in body["models"]}
    assert set(tasks) == {"image-to-shape", "completion", "classify"}
    img = tasks["image-to-shape"]
    assert img["depth"] == 5 and img["min_depth"] == 4 and img["input"]["image"]["size"] == 64
    for name, g in img["graphs"].items():
        assert g["sha256"] == sha256_file(models_dir / "image-to-shape" / g["file"])


@pytest.mark.parametrize("surface", ["watertight", "patches"])
@pytest.mark.parametrize("fmt, media", [("glb", "model/gltf-binary"), ("gltf", "model/gltf+json"),
                                        ("ply", "application/x-ply"), ("obj", "model/obj")])
def test_image_to_shape_returns_the_bundle_s_decoded_surface_in_every_format(client, models_dir, fmt, media, surface):
    r = client.post(f"/v1/image-to-shape?format={fmt}&surface={surface}", files={"image": ("p.png", photo(), "image/png")})
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == media
    assert r.headers["content-disposition"] == f'attachment; filename="shape.{fmt}"'
    assert r.headers["x-model-name"] == "image-to-shape" and "+" in r.headers["x-model-version"]
    mesh = trimesh.load(io.BytesIO(r.content), file_type=fmt, force="mesh", process=False)
    # the same photo through the bundle directly gives the same patches
    bundle = load_bundle(models_dir / "image-to-shape")
    from model.image.frame import load_and_prepare
    runtime = Runtime(bundle, threads=1)
    octree = runtime.decode(runtime.encode_image(load_and_prepare(photo(), bundle.image_spec())[None]))
    m = surface_mesh(octree, surface)
    want = trimesh.Trimesh(m.vertices, m.faces, process=False)
    assert r.headers["x-surface"] == surface and r.headers["x-mesh-closed"] == str(m.closed).lower()
    assert m.closed == (surface == "watertight")
    assert int(r.headers["x-mesh-faces"]) == len(want.faces) > 0
    assert int(r.headers["x-octree-nodes"]) == sum(octree.nodes_per_depth())
    assert r.headers["x-octree-leaves"] == ",".join(f"{d}:{n}" for d, n in enumerate(octree.leaves_per_depth()) if n)
    assert np.allclose(mesh.bounds, want.bounds, atol=1e-5)
    assert mesh.area == pytest.approx(want.area, rel=1e-4)
    assert np.abs(mesh.bounds).max() <= 0.5 + 1e-4            # unit cube centred at 0


def test_accept_header_chooses_the_format_and_depth_gives_a_coarser_level(client):
    r = client.post("/v1/image-to-shape", files={"image": ("p.png", photo())}, headers={"Accept": "model/obj"})
    assert r.headers["content-type"] == "model/obj"
    fine = client.post("/v1/image-to-shape", files={"image": ("p.png", photo())})
    coarse = client.post("/v1/image-to-shape?depth=4", files={"image": ("p.png", photo())})
    assert fine.headers["content-type"] == "model/gltf-binary"
    assert max(int(p.split(":")[0]) for p in coarse.headers["x-octree-leaves"].split(",")) == 4
    assert int(coarse.headers["x-octree-nodes"]) < int(fine.headers["x-octree-nodes"])
    colored = client.post("/v1/image-to-shape?color_by_depth=true&format=ply", files={"image": ("p.png", photo())})
    mesh = trimesh.load(io.BytesIO(colored.content), file_type="ply", process=False)
    assert len(np.unique(mesh.visual.face_colors[:, :3], axis=0)) >= 2


def _npz(pts, normals=None) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, points=pts, **({"normals": normals} if normals is not None else {}))
    return buf.getvalue()


def _npy(arr) -> bytes:
    buf = io.BytesIO()
    np.save(buf, arr)
    return buf.getvalue()


def _uploads(pts: np.ndarray, normals: np.ndarray) -> dict[str, bytes]:
    cloud = trimesh.PointCloud(pts)
    return {
        "scan.ply": trimesh.PointCloud(pts).export(file_type="ply"),             # binary
        "scan_ascii.ply": cloud.export(file_type="ply", encoding="ascii"),
        "scan.xyz": "\n".join(" ".join(f"{v:.6f}" for v in p) for p in pts).encode(),
        "scan.txt": "\n".join(" ".join(f"{v:.6f}" for v in row) for row in np.hstack([pts, normals])).encode(),
        "scan.npy": _npy(pts.astype(np.float32)),
        "scan.npz": _npz(pts, normals),
        "scan.obj": "\n".join(f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in pts).encode(),
        "scan.csv": b"\xef\xbb\xbfX,Y,Z,Nx,Ny,Nz\r\n"                           # a spreadsheet's export
                    + "\r\n".join(",".join(f"{v:.6f}" for v in row) for row in np.hstack([pts, normals])).encode(),
    }


def test_complete_accepts_every_point_format_and_answers_in_the_input_frame(client, clouds):
    pts = partial_cloud(clouds)[::4]
    normals = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    lo, hi = pts.min(0), pts.max(0)
    for name, data in _uploads(pts, normals).items():
        r = client.post("/v1/complete?format=ply", files={"points": (name, data)})
        assert r.status_code == 200, (name, r.text)
        assert r.headers["x-model-name"] == "completion-test"
        mesh = trimesh.load(io.BytesIO(r.content), file_type="ply", process=False)
        centre, extent = (lo + hi) / 2, (hi - lo).max()
        # the decoded cube is the input's bounding cube (padded): the output is in the scan's frame
        assert np.all(np.abs(mesh.vertices - centre) <= extent), name
        assert np.abs(mesh.vertices.mean(0) - centre).max() < 0.5 * extent


def test_complete_drops_points_far_from_the_scan_and_says_how_many(client, clouds):
    pts = partial_cloud(clouds)[::4]
    lo, hi = pts.min(0), pts.max(0)
    extent = (hi - lo).max()
    stray = pts[:5] + [1000 * extent, 0, 0]                       # a reflection far behind the object
    meshes = {}
    for name, cloud in (("clean", pts), ("strays", np.r_[pts, stray])):
        r = client.post("/v1/complete?format=ply", files={"points": ("scan.npy", _npy(cloud))})
        assert r.status_code == 200, r.text
        assert r.headers["x-points-dropped"] == ("5" if name == "strays" else "0")
        meshes[name] = trimesh.load(io.BytesIO(r.content), file_type="ply", process=False)
    # framed by the scan alone: the same output as without the strays, near the scan, not a speck
    assert np.allclose(meshes["strays"].vertices, meshes["clean"].vertices)
    assert np.all(np.abs(meshes["strays"].vertices - (lo + hi) / 2) <= extent)
    for endpoint in ("octree", "classify"):                       # the same rule, the same report
        answers = [client.post(f"/v1/{endpoint}", files={"shape": ("scan.npy", _npy(cloud))})
                   for cloud in (pts, np.r_[pts, stray])]
        assert [r.status_code for r in answers] == [200, 200]
        assert [r.headers["x-points-dropped"] for r in answers] == ["0", "5"]
        assert answers[0].content == answers[1].content


def test_complete_never_mirrors_a_flat_sheet_and_says_so(client):
    """A scanned relief (a flat strip, a head at one end): its outline lands on itself mirrored,
    but a sheet is completed as sent, and X-Symmetry says why."""
    rng = np.random.default_rng(0)
    strip = rng.uniform([-0.5, -0.08, 0.0], [0.5, 0.08, 0.0], (6000, 3))
    head = rng.uniform([0.38, -0.13, 0.0], [0.5, 0.13, 0.0], (600, 3))
    pts = np.r_[strip, head] + rng.normal(0, 0.005, (6600, 3))
    r = client.post("/v1/complete?format=ply", files={"points": ("relief.npy", _npy(pts))})
    assert r.status_code == 200, r.text
    used, plane, support = r.headers["x-symmetry"].split("; ")
    assert used == "not mirrored (a sheet)" and abs(float(plane.removeprefix("plane x="))) < 0.05
    assert float(support.removeprefix("support=")) >= 0.85            # its outline alone would pass


def test_complete_and_classify_turn_a_z_up_upload_upright_and_the_completed_shape_back(client, clouds):
    from model.octree.geometry import to_y_up

    turn = to_y_up("z")                                   # z-up coordinates -> the models' y-up ones
    pts, normals = clouds[-1][0][::4] * 40.0, clouds[-1][1][::4]
    upright = _npz(pts, normals)
    lying = _npz(pts @ turn, normals @ turn)              # the same scan as a z-up scanner writes it
    meshes = {}
    for name, data, query in (("y", upright, ""), ("z", lying, "&up=z"), ("z as y", lying, "")):
        r = client.post(f"/v1/complete?format=ply{query}", files={"points": ("s.npz", data)})
        assert r.status_code == 200, r.text
        meshes[name] = (trimesh.load(io.BytesIO(r.content), file_type="ply", process=False), r.headers["x-symmetry"])
    (a, sym_a), (b, sym_b), (c, _) = meshes["y"], meshes["z"], meshes["z as y"]
    assert sym_a == sym_b                                  # the plane x = c is the same plane in both frames
    assert np.array_equal(a.faces, b.faces)
    assert np.allclose(b.vertices @ turn.T, a.vertices, atol=1e-6)     # completed upright, answered z-up
    assert len(c.vertices) != len(a.vertices) or not np.allclose(c.vertices @ turn.T, a.vertices, atol=1e-3)
    probs = {}
    for name, data, query in (("y", upright, ""), ("z", lying, "&up=z"), ("z as y", lying, "")):
        r = client.post(f"/v1/classify?top_k=50{query}", files={"shape": ("s.npz", data)})
        assert r.status_code == 200, r.text
        probs[name] = {t["category"]: t["probability"] for t in r.json()["top"]}
    assert probs["z"] == pytest.approx(probs["y"], abs=1e-6)
    assert probs["z as y"] != pytest.approx(probs["y"], abs=1e-3)
    for endpoint, field in (("complete", "points"), ("classify", "shape")):
        r = client.post(f"/v1/{endpoint}?up=w", files={field: ("s.npz", upright)})
        assert r.status_code == 422 and "up" in r.text


def test_octree_endpoint_builds_the_adaptive_octree_of_a_mesh(client):
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=3.0)
    data = sphere.export(file_type="obj").encode() if isinstance(sphere.export(file_type="obj"), str) \
        else sphere.export(file_type="obj")
    r = client.post("/v1/octree?depth=5&format=glb", files={"shape": ("s.obj", data)})
    assert r.status_code == 200, r.text
    leaves = dict(p.split(":") for p in r.headers["x-octree-leaves"].split(","))
    assert set(leaves) <= {"4", "5"} and "X-Model-Name" not in r.headers
    mesh = trimesh.load(io.BytesIO(r.content), file_type="glb", force="mesh")
    radius = np.linalg.norm(mesh.vertices, axis=1)
    assert np.abs(radius - 3.0).max() < 3.0 * 2 / 32         # patches lie within a few voxels of the sphere
    full = client.post("/v1/octree?depth=5&full=true", files={"shape": ("s.obj", data)})
    assert set(dict(p.split(":") for p in full.headers["x-octree-leaves"].split(","))) == {"5"}


@pytest.mark.parametrize("fmt", ["stl", "off", "ply", "glb", "obj"])
def test_octree_endpoint_recognises_meshes_by_their_bytes_whatever_the_file_name(client, fmt):
    """The box's surface at depth 4 (a cell is 0.13 wide): the patches overhang their faces by up to
    0.4 cell, the closed surface by up to 0.7 cell where leaves span the box's edges."""
    data = trimesh.creation.box(extents=(2.0, 1.0, 0.5)).export(file_type=fmt)
    data = data.encode() if isinstance(data, str) else data
    for surface, atol in (("patches", 0.05), ("watertight", 0.09)):
        r = client.post(f"/v1/octree?depth=4&format=ply&surface={surface}", files={"shape": ("upload.bin", data)})
        assert r.status_code == 200, (fmt, r.text)
        mesh = trimesh.load(io.BytesIO(r.content), file_type="ply", process=False)
        assert np.allclose(mesh.bounds, [[-1, -0.5, -0.25], [1, 0.5, 0.25]], atol=atol), (surface, mesh.bounds)
        assert mesh.is_watertight == (surface == "watertight") and r.headers["x-surface"] == surface


def test_openapi_documents_every_endpoint_with_its_models(client):
    spec = client.get("/openapi.json").json()
    for path in ("/v1/image-to-shape", "/v1/complete", "/v1/octree", "/v1/classify", "/v1/models",
                 "/healthz", "/readyz", "/metrics"):
        assert path in spec["paths"], path
    assert "ErrorBody" in spec["components"]["schemas"] and "ModelInfo" in spec["components"]["schemas"]
    assert client.get("/docs").status_code == 200


def test_metrics_count_requests_and_time_each_stage(client):
    client.post("/v1/image-to-shape", files={"image": ("p.png", photo())})
    client.post("/v1/image-to-shape", files={"image": ("p.png", b"not an image")})
    text = client.get("/metrics").text
    assert 'aocnn_requests_total{endpoint="/v1/image-to-shape",status="200"}' in text
    assert 'aocnn_requests_total{endpoint="/v1/image-to-shape",status="415"}' in text
    for stage in ("decode_input", "encoder", "decoder", "mesh_encode"):
        assert f'aocnn_stage_seconds_count{{stage="{stage}"}}' in text
    assert "aocnn_queue_seconds_count" in text and "aocnn_inferences_in_flight 0.0" in text


def test_api_keys_when_configured(models_dir):
    with make_client(models_dir, api_keys="k1, k2") as c:
        assert c.get("/v1/models").status_code == 401
        r = c.get("/v1/models", headers={"Authorization": "Bearer nope"})
        assert r.status_code == 401 and r.headers["www-authenticate"] == "Bearer"
        assert r.json()["error"]["code"] == "unauthorized"
        assert c.get("/v1/models", headers={"Authorization": "Bearer k2"}).status_code == 200
        assert c.get("/healthz").status_code == 200                 # probes need no key


def test_cors_allows_the_configured_origin_only(models_dir):
    with make_client(models_dir, cors_origins="http://demo.example") as c:
        ok = c.options("/v1/models", headers={"Origin": "http://demo.example", "Access-Control-Request-Method": "GET"})
        assert ok.headers.get("access-control-allow-origin") == "http://demo.example"
        bad = c.options("/v1/models", headers={"Origin": "http://evil.example", "Access-Control-Request-Method": "GET"})
        assert "access-control-allow-origin" not in bad.headers


def _torch_probabilities(model, pts, normals, depth: int, rotations: int = 1) -> np.ndarray:
    """The classifier's probabilities (mean over ``rotations`` about y) through torch."""
    import torch

    from model.nn.tensors import OctreeTensors
    from model.octree import build_octree, validate
    from model.octree.batch import merge_octrees
    from model.octree.geometry import axis_rotation

    trees = []
    for k in range(rotations):
        r = axis_rotation(2 * np.pi * k / 12, "y")
        trees.append(build_octree(validate(pts @ r.T, normals @ r.T), depth, adaptive=True))
    with torch.no_grad():
        return torch.softmax(model.logits(OctreeTensors.from_octree(merge_octrees(trees))), 1).numpy()


def test_classify_returns_the_models_top_categories_with_and_without_the_12_rotation_vote(client, exported, clouds):
    model, cfg, _ = exported("classify-aocnn")
    pts, normals = clouds[-1][0][::10], clouds[-1][1][::10]
    data = _npz(pts, normals)
    for vote, rotations in (("false", 1), ("true", 12)):
        r = client.post(f"/v1/classify?top_k=2&vote={vote}", files={"shape": ("s.npz", data)})
        assert r.status_code == 200, r.text
        body = r.json()
        assert body["model"] == "classify-test" and len(body["top"]) == 2
        assert {"decode_input", "octree_build", "encoder"} <= {t.split(";")[0] for t in r.headers["server-timing"].split(", ")}
        per_rotation = _torch_probabilities(model, pts, normals, cfg.depth, rotations)
        want, votes = per_rotation.mean(0), np.bincount(per_rotation.argmax(1), minlength=len(cfg.categories))
        assert body["rotations"] == rotations
        got = {t["category"]: t for t in body["top"]}
        probabilities = [t["probability"] for t in body["top"]]
        assert probabilities == sorted(probabilities, reverse=True)
        assert all(abs(t["probability"] - want[cfg.categories.index(c)]) <= 1e-4 for c, t in got.items())
        # which category ranks higher, or takes a rotation's vote, is torch's unless the two are
        # within rounding (another CPU's kernels may break such a tie the other way)
        top = np.sort(per_rotation, 1)
        if float((top[:, -1] - top[:, -2]).min()) > 1e-4:
            assert all(t["votes"] == votes[cfg.categories.index(c)] for c, t in got.items())
        ranked = np.sort(want)[::-1]
        if ranked[1] - ranked[2] > 1e-4:
            assert set(got) == {cfg.categories[i] for i in np.argsort(-want)[:2]}
    every = client.post("/v1/classify?top_k=50&vote=true", files={"shape": ("s.npz", data)}).json()["top"]
    assert sorted(t["category"] for t in every) == sorted(cfg.categories)
    assert sum(t["votes"] for t in every) == 12
    assert sum(t["probability"] for t in every) == pytest.approx(1, abs=1e-4)
    assert client.post("/v1/classify", files={"shape": ("s.xyz", b"0 0 0\n1 0 0\n2 0 0\n")}).status_code == 400


def test_classify_and_complete_answer_503_without_their_bundles(models_dir, tmp_path):
    import shutil

    shutil.copytree(models_dir / "image-to-shape", tmp_path / "image-to-shape")
    with make_client(tmp_path) as c:
        for path, field in (("/v1/classify", "shape"), ("/v1/complete", "points")):
            r = c.post(path, files={field: ("s.xyz", b"0 0 0\n1 0 0\n0 1 0\n")})
            assert r.status_code == 503 and r.json()["error"]["code"] == "no_model" and r.headers["retry-after"]


def test_complete_builds_the_training_input_octree_with_and_without_normals(client, exported, clouds):
    """The service's completion input is :func:`scan_octree` of the upload (normals estimated when
    absent), exactly the octrees the model was trained on, and the output is in the scan's frame.
    The expected answer is the bundle's own decode of that octree (its graphs are torch's, step by
    step: tests/export; a whole decode of a random decoder is not comparable across runtimes)."""
    from export.bundle import load_bundle
    from export.runtime import Runtime
    from model.octree import scan_frame, scan_octree, validate
    from model.octree.batch import split_octree
    from model.octree.fuse import keep_scan
    from model.octree.symmetry import symmetrize

    _, cfg, folder = exported("completion-aocnn")
    runtime = Runtime(load_bundle(folder), threads=1)
    pts = partial_cloud(clouds)[::4]
    normals = clouds[-1][1][clouds[-1][0][:, 0] < np.quantile(clouds[-1][0][:, 0], 0.7)][::4]
    for name, data, given in (("scan.npz", _npz(pts, normals), normals), ("scan.npy", _npy(pts), None)):
        for symmetry in (True, False):
            cloud = validate(pts, given)
            if symmetry:
                cloud, mirror = symmetrize(cloud)
            tree = scan_octree(cloud, cfg.depth)
            out = split_octree(runtime.decode(runtime.encode_octree(tree)), neighbors=False)[0]
            out.normalizations = [scan_frame(cloud.points)]
            for query, want_tree in (("", keep_scan(out, tree)), ("&keep_scan=false", out)):   # the default first
                query += "" if symmetry else "&symmetry=false"
                r = client.post(f"/v1/complete?format=ply{query}", files={"points": (name, data)})
                assert r.status_code == 200, r.text
                assert r.headers["x-keep-scan"] == ("false" if "keep_scan" in query else "true")
                assert r.headers["x-symmetry"] == ("off" if not symmetry else
                                                   f"{'mirrored' if mirror.supported() else 'not mirrored'}; "
                                                   f"plane x={mirror.offset:.6g}; support={mirror.support:.3f}")
                got = trimesh.load(io.BytesIO(r.content), file_type="ply", process=False)
                m = surface_mesh(want_tree)
                want = trimesh.Trimesh(m.vertices, m.faces, process=False)
                assert len(want.faces) > 0 and np.allclose(got.bounds, want.bounds, atol=1e-3 * np.ptp(pts, 0).max())
                assert got.area == pytest.approx(want.area, rel=1e-3)
                assert r.headers["x-surface"] == "patches" and r.headers["x-mesh-closed"] == "false"  # the default


def test_complete_decodes_with_the_bundles_keep_scan_bias_only_when_it_keeps_the_scan(models_dir, exported, clouds,
                                                                                     tmp_path):
    """A bias far beyond any logit empties every decoded octant: the default answer is then the
    scan's own octree, leaf for leaf; keep_scan=false is the network's output, without the bias."""
    import json
    import shutil

    from model.octree import scan_octree, validate

    _, cfg, _ = exported("completion-aocnn")
    root = tmp_path / "models"
    shutil.copytree(models_dir, root)
    meta = json.loads((root / "completion" / "model.json").read_text())
    meta["output"]["keep_scan"] = {"empty_bias": {str(d): 1e4 for d in range(2, cfg.depth + 1)}}
    (root / "completion" / "model.json").write_text(json.dumps(meta))
    pts = partial_cloud(clouds)[::4]
    scan = scan_octree(validate(pts, None), cfg.depth)
    want = ",".join(f"{d}:{n}" for d, n in enumerate(scan.leaves_per_depth()) if n)
    with make_client(root) as c:
        kept = c.post("/v1/complete?format=ply&symmetry=false", files={"points": ("scan.npy", _npy(pts))})
        plain = c.post("/v1/complete?format=ply&keep_scan=false&symmetry=false",
                       files={"points": ("scan.npy", _npy(pts))})
    assert kept.status_code == plain.status_code == 200, (kept.text, plain.text)
    assert kept.headers["x-octree-leaves"] == want
    assert plain.headers["x-octree-leaves"] != want and int(plain.headers["x-mesh-faces"]) > 0


@pytest.mark.parametrize("accept, fmt", [
    ("model/obj;q=0.5, application/x-ply;q=0.9", "ply"), ("model/obj, application/x-ply", "obj"),
    ("text/html, */*;q=0.1", "glb"), ("model/gltf+json;q=0, model/obj;q=0.2", "obj"),
    ("image/png", "glb"), ("model/obj;q=abc, model/gltf+json", "gltf"), (None, "glb")])
def test_accept_header_negotiation(accept, fmt):
    from service.meshes import choose_format
    assert choose_format(None, accept) == fmt
    assert choose_format("ply", accept) == "ply"                 # the format parameter wins


def test_surface_and_face_budget_parameters(client):
    data = trimesh.creation.icosphere(3).export(file_type="obj").encode()
    r = client.post("/v1/octree?depth=6&format=ply&surface=watertight", files={"shape": ("s.obj", data)})
    assert r.status_code == 200 and r.headers["x-surface"] == "watertight" and r.headers["x-mesh-closed"] == "true"
    full = int(r.headers["x-mesh-faces"])
    r = client.post("/v1/octree?depth=6&format=ply&surface=watertight&faces=500", files={"shape": ("s.obj", data)})
    assert r.status_code == 200 and int(r.headers["x-mesh-faces"]) <= 500 < full
    mesh = trimesh.load(io.BytesIO(r.content), file_type="ply", process=False)
    assert len(mesh.faces) <= 500 and mesh.is_watertight and r.headers["x-mesh-closed"] == "true"
    bad = client.post("/v1/octree?depth=6&surface=smooth", files={"shape": ("s.obj", data)})
    assert bad.status_code == 422 and "'watertight' or 'patches'" in bad.json()["error"]["message"]
    bad = client.post("/v1/octree?depth=6&surface=patches&faces=500", files={"shape": ("s.obj", data)})
    assert bad.status_code == 422 and "surface=watertight" in bad.json()["error"]["message"]
    bad = client.post("/v1/octree?depth=6&faces=500", files={"shape": ("s.obj", data)})     # patches by default
    assert bad.status_code == 422 and "surface=watertight" in bad.json()["error"]["message"]
    bad = client.post("/v1/octree?depth=6&surface=watertight&faces=2", files={"shape": ("s.obj", data)})
    assert bad.status_code == 422 and "faces" in bad.json()["error"]["message"]


def test_the_warm_up_compiles_the_normal_estimation_before_the_first_scan(models_dir):
    """A fresh process: after the warm-up, the compiled kernels of normal estimation, the symmetry
    search, the octree build, the scan fusion and the closed surface have their machine code (a
    first completion or closed-surface request does not spend seconds compiling them; the photo
    mask's kernel: tests/service/test_foreground.py)."""
    kernels = ("orient.covariance_rows, orient.spanning_tree, orient.propagate_signs, knn._query, knn._within, "
               "probe_search._grid_probes, probe_search._edge_probes, clusters._nearest_on_fans, flood._repair_round, "
               "flood._reached, flood._dilated, checks._fan_counts, checks._edge_faults, graph._components, graph._close_pairs, "
               "clusters._merged_faces, fuse._walk, fuse._by_depth, fuse._fill_level, orient._edges_by_weight, "
               "orient.radix_order, keys.cell_keys, build._rows_in_order, frame._differing_bounds")
    code = ("import sys; from service.engine import Engine; from service.settings import Settings; "
            "from model.octree import build, fuse, keys, orient, knn, probe_search; from model.image import frame; "
            "from model.surface import checks, clusters, flood, graph; "
            "e = Engine(Settings(models_dir=sys.argv[1])); e.load(); "
            f"before = [len(f.signatures) for f in ({kernels})]; "
            "e.warm_up(); "
            f"after = [len(f.signatures) for f in ({kernels})]; "
            "print(before, after)")
    out = subprocess.run([sys.executable, "-c", code, str(models_dir)], capture_output=True, text=True, timeout=600,
                         cwd=REPO)
    assert out.returncode == 0, out.stderr[-2000:]
    count = kernels.count(",") + 1
    assert out.stdout.strip().splitlines()[-1] == f"{[0] * count} {[1] * count}", out.stdout
