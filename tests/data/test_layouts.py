"""Dataset layouts and mesh loading on tiny fabricated trees."""

from pathlib import Path

import numpy as np
import pytest
import trimesh

from model.data.layouts import (
    folder_category,
    iter_mesh_folder,
    iter_modelnet40,
    iter_r2n2,
    iter_shapenet,
    load_mesh,
    read_off,
    y_up,
)

CUBE_OFF_BODY = "\n".join(
    ["-1 -1 -1", "1 -1 -1", "1 1 -1", "-1 1 -1", "-1 -1 1", "1 -1 1", "1 1 1", "-1 1 1",
     "4 0 3 2 1", "4 4 5 6 7", "4 0 1 5 4", "4 2 3 7 6", "4 1 2 6 5", "4 0 4 7 3"]
)


def _write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def test_read_off_fused_header_and_quads(tmp_path):
    fused = _write(tmp_path / "a.off", "OFF8 6 0\n" + CUBE_OFF_BODY + "\n")
    normal = _write(tmp_path / "b.off", "OFF\n# comment\n8 6 0\n" + CUBE_OFF_BODY + "\n")
    for p in (fused, normal):
        m = read_off(p)
        assert m.vertices.shape == (8, 3) and m.faces.shape == (12, 3)
        assert np.isclose(m.area, 24.0)
        assert np.isclose(abs(m.volume), 8.0)
    assert np.isclose(load_mesh(fused).area, 24.0)


def test_load_mesh_errors_and_scene(tmp_path):
    with pytest.raises(ValueError, match="empty"):
        load_mesh(_write(tmp_path / "e.off", ""))
    with pytest.raises(ValueError, match="shorter"):
        load_mesh(_write(tmp_path / "t.off", "OFF\n8 6 0\n0 0 0\n"))
    with pytest.raises(ValueError, match="no such file"):
        load_mesh(tmp_path / "missing.obj")
    with pytest.raises(ValueError, match=str(tmp_path / "x.obj").replace("\\", "\\\\")):
        load_mesh(_write(tmp_path / "x.obj", "# nothing here\n"))
    # An OBJ with two objects loads as a Scene in trimesh: it must come back as one mesh.
    a, b = trimesh.creation.box(), trimesh.creation.box()
    b.apply_translation([3, 0, 0])
    scene = trimesh.Scene([a, b])
    path = tmp_path / "two.obj"
    scene.export(path)
    m = load_mesh(path)
    assert isinstance(m, trimesh.Trimesh) and len(m.faces) == 24
    assert np.isclose(m.bounds[1, 0], 3.5)


def test_mesh_folder_yields_each_mesh_file_as_a_test_shape(tmp_path):
    root = tmp_path / "mine"
    _write(root / "mn40_chair_0001.off", "OFF8 6 0\n" + CUBE_OFF_BODY)
    trimesh.creation.box().export(root / "Bracket.STL")
    _write(root / "notes.txt", "not a mesh")
    _write(root / "sub" / "table_1.off", "OFF\n8 6 0\n" + CUBE_OFF_BODY)        # only the folder itself is read
    recs = list(iter_mesh_folder(root))
    assert [(r.category, r.shape_id, r.split, r.mesh_path.name) for r in recs] == [
        ("unknown", "Bracket", "test", "Bracket.STL"), ("chair", "mn40_chair_0001", "test", "mn40_chair_0001.off")]
    assert np.isclose(load_mesh(recs[0].mesh_path).area, 6.0)              # the unit box, read as STL
    trimesh.creation.box().export(root / "Bracket.obj")
    with pytest.raises(ValueError, match="share the shape id 'Bracket'"):
        list(iter_mesh_folder(root))
    with pytest.raises(ValueError, match="holds no mesh files"):
        list(iter_mesh_folder(_write(tmp_path / "empty" / "readme.md", "").parent))


def test_folder_category_is_a_category_named_as_a_word():
    assert folder_category("mn40_airplane_0003") == "airplane"
    assert folder_category("Old-Chair 2") == "chair"
    assert folder_category("chairman") == "unknown"                      # a word, not a substring
    assert folder_category("chair_and_table") == "unknown"               # two named: neither
    assert folder_category("stanford_bunny") == "unknown"


def test_y_up_turns_the_named_axis_to_y_by_a_rotation():
    tall = trimesh.creation.box(extents=(1.0, 2.0, 3.0))          # longest along z
    for up, along in (("z", 2), ("x", 0)):
        src = trimesh.creation.box(extents=np.roll((1.0, 2.0, 3.0), along - 2))
        turned = y_up(src, up)
        assert np.isclose(turned.extents[1], src.extents[along])   # the up axis now spans y
        assert np.isclose(turned.volume, src.volume) and turned.is_winding_consistent
        assert turned.volume > 0                                   # a rotation: the faces still face out
    assert y_up(tall, "y") is tall
    apex = trimesh.Trimesh(vertices=[[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]],
                           faces=[[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    assert np.allclose(y_up(apex, "z").vertices[3], [0, 1, 0])     # +z goes to +y
    assert np.allclose(y_up(apex, "x").vertices[1], [0, 1, 0])     # +x goes to +y
    with pytest.raises(ValueError, match="up must be one of"):
        y_up(tall, "w")


def test_modelnet40(tmp_path):
    root = tmp_path / "ModelNet40"
    _write(root / "chair" / "train" / "chair_0001.off", "OFF8 6 0\n" + CUBE_OFF_BODY)
    _write(root / "chair" / "test" / "chair_0890.off", "OFF\n8 6 0\n" + CUBE_OFF_BODY)
    _write(root / "airplane" / "train" / "airplane_0001.off", "OFF\n8 6 0\n" + CUBE_OFF_BODY)
    recs = list(iter_modelnet40(root))
    assert [(r.category, r.shape_id, r.split) for r in recs] == [
        ("airplane", "airplane_0001", "train"), ("chair", "chair_0001", "train"), ("chair", "chair_0890", "test")]
    assert all(len(load_mesh(r.mesh_path).faces) == 12 for r in recs)
    with pytest.raises(ValueError, match="ModelNet40"):
        list(iter_modelnet40(tmp_path / "chair_empty"))
    (tmp_path / "other").mkdir()
    with pytest.raises(ValueError, match=str(tmp_path / "other")):
        list(iter_modelnet40(tmp_path / "other"))


def _shapenet_tree(root: Path) -> None:
    obj = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
    for syn, model in [("03001627", "c1"), ("03001627", "c2"), ("02958343", "car1"), ("02747177", "bin1")]:
        _write(root / syn / model / "models" / "model_normalized.obj", obj)
    (root / "03001627" / "broken" / "models").mkdir(parents=True)


def test_shapenet_hash_and_csv_splits(tmp_path):
    root = tmp_path / "ShapeNetCore.v2"
    _shapenet_tree(root)
    recs = list(iter_shapenet(root))
    assert [(r.category, r.shape_id) for r in recs] == [("car", "car1"), ("chair", "c1"), ("chair", "c2")]
    assert all(r.split in ("train", "val", "test") for r in recs)
    assert [r.split for r in recs] == [r.split for r in iter_shapenet(root)]
    csv = _write(tmp_path / "all.csv", "id,synsetId,subSynsetId,modelId,split\n"
                 "1,3001627,3001627,c1,test\n2,3001627,3001627,c2,val\n3,2958343,2958343,car1,train\n")
    recs = {r.shape_id: r.split for r in iter_shapenet(root, split_csv=csv)}
    assert recs == {"c1": "test", "c2": "val", "car1": "train"}
    assert len(load_mesh(root / "02958343" / "car1" / "models" / "model_normalized.obj").faces) == 1
    with pytest.raises(ValueError, match="ShapeNetCore"):
        list(iter_shapenet(tmp_path))


def test_r2n2_renderings(tmp_path):
    root = tmp_path / "ShapeNetRendering"
    rd = root / "02691156" / "plane1" / "rendering"
    _write(rd / "renderings.txt", "00.png\n01.png\n")
    _write(rd / "rendering_metadata.txt", "293.77 25.53 0 0.7229 25\n12.5 28.1 0 0.81 25\n")
    for n in ("00.png", "01.png"):
        _write(rd / n, "png")
    shapenet = tmp_path / "sn"
    _write(shapenet / "02691156" / "plane1" / "models" / "model_normalized.obj", "v 0 0 0\n")
    (rec,) = list(iter_r2n2(root, shapenet_root=shapenet))
    assert rec.category == "airplane" and rec.shape_id == "plane1" and rec.synset == "02691156"
    assert [p.name for p in rec.image_paths] == ["00.png", "01.png"]
    assert rec.metadata[0].azimuth == pytest.approx(293.77)
    assert rec.metadata[1].distance_ratio == pytest.approx(0.81) and rec.metadata[1].fov == 25.0
    assert rec.mesh_path == shapenet / "02691156" / "plane1" / "models" / "model_normalized.obj"
    _write(rd / "rendering_metadata.txt", "293.77 25.53 0 0.7229\n12.5 28.1 0 0.81 25\n")
    with pytest.raises(ValueError, match="expected 5 numbers"):
        list(iter_r2n2(root))
    with pytest.raises(ValueError, match="R2N2"):
        list(iter_r2n2(shapenet / "02691156" / "plane1"))
