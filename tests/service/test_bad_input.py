"""Hostile and broken inputs, by class: each gets a 4xx JSON error saying what is wrong, never a
500, a hang or a file left behind; overload gets 503 with Retry-After; bad bundles stop startup."""

from __future__ import annotations

import asyncio
import io
import os
import pickle
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from service.engine import Engine, StartupError
from service.errors import ServiceError
from service.limiter import Limiter, plan_threads
from service.metrics import Metrics
from service.settings import Settings

from ..torchless import run_without_torch
from .conftest import make_client
from .test_api import _npy, photo, png

ROOT = Path(__file__).resolve().parents[2]


def _err(r, status: int, code: str | None = None) -> dict:
    assert r.status_code == status, (r.status_code, r.text)
    body = r.json()["error"]
    assert body["message"] and body["hint"]
    if code:
        assert body["code"] == code, body
    return body


def _gif_bomb() -> bytes:
    buf = io.BytesIO()
    Image.new("1", (9000, 9000)).save(buf, format="PNG")        # 81 Mpixel, a few kB
    return buf.getvalue()


IMAGES = {
    "empty file": (b"", 400, "empty_input"),
    "text": (b"hello, I am not a picture", 415, "unsupported_image"),
    "truncated png": (photo()[:300], 400, "invalid_image"),
    "fully transparent": (png(np.zeros((20, 20, 4), np.uint8)), 422, "no_object"),
    "nearly transparent": (png(np.full((20, 20, 4), 1, np.uint8)), 422, "no_object"),
    "a 2-pixel object": (png(np.pad(np.full((2, 2, 4), 255, np.uint8), ((9, 9), (9, 9), (0, 0)))), 422, "no_object"),
    "decompression bomb": (_gif_bomb(), 413, "image_too_large"),
    "pdf claiming to be png": (b"%PDF-1.4\n" + b"0" * 100, 415, "unsupported_image"),
}


@pytest.mark.parametrize("case", sorted(IMAGES))
def test_bad_images(client, case):
    data, status, code = IMAGES[case]
    r = client.post("/v1/image-to-shape", files={"image": ("x.png", data, "image/png")})
    _err(r, status, code)


def test_missing_or_wrong_fields_and_bad_parameters(client):
    _err(client.post("/v1/image-to-shape"), 422, "invalid_request")
    assert "image" in _err(client.post("/v1/image-to-shape", files={"picture": ("p.png", photo())}), 422)["message"]
    _err(client.post("/v1/image-to-shape", content=b"raw bytes", headers={"Content-Type": "image/png"}), 422)
    _err(client.post("/v1/image-to-shape?format=stl", files={"image": ("p.png", photo())}), 422)
    _err(client.post("/v1/image-to-shape?depth=3", files={"image": ("p.png", photo())}), 422, "invalid_depth")
    _err(client.post("/v1/image-to-shape?depth=99", files={"image": ("p.png", photo())}), 422)
    _err(client.post("/v1/octree?depth=11", files={"shape": ("s.xyz", b"0 0 0")}), 422)
    _err(client.post("/v1/octree?depth=9", files={"shape": ("s.xyz", b"0 0 0")}), 422, "invalid_depth")
    _err(client.post("/v1/octree?threshold=-1", files={"shape": ("s.xyz", b"0 0 0")}), 422)
    _err(client.get("/v1/nothing-here"), 404)
    _err(client.get("/v1/image-to-shape"), 405)


def _zip_bytes() -> bytes:
    import zipfile
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        z.writestr("notes.txt", "not arrays")
    return buf.getvalue()


def _npz_bytes(**arrays) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


MARKER = os.path.join(tempfile.gettempdir(), f"aocnn-unpickled-{os.getpid()}")
"""Created if any upload's pickle is ever unpickled (np.load with allow_pickle=True)."""


class Trap:
    """Unpickling this opens (creates) :data:`MARKER`: an observable side effect, nothing worse."""

    def __reduce__(self):
        return (open, (MARKER, "w"))


def _object_npy() -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.array([Trap(), None], dtype=object), allow_pickle=True)
    return buf.getvalue()


def _object_npz() -> bytes:
    buf = io.BytesIO()
    np.savez(buf, points=np.array([Trap(), None], dtype=object))
    return buf.getvalue()


def _ply(n_declared: int, n_given: int) -> bytes:
    head = (f"ply\nformat ascii 1.0\nelement vertex {n_declared}\nproperty float x\nproperty float y\n"
            f"property float z\nend_header\n")
    return (head + "".join(f"{i} {i % 7} {i % 3}\n" for i in range(n_given))).encode()


def _sphere(n=2000, seed=0):
    p = np.random.default_rng(seed).normal(size=(n, 3))
    return p / np.linalg.norm(p, axis=1, keepdims=True)


def _png_bytes() -> bytes:
    return png(np.full((16, 16, 3), 200, np.uint8))


def _text(rows) -> bytes:
    return "".join(" ".join(f"{v:.6g}" for v in r) + "\n" for r in rows).encode()


_t = np.arange(1, 301)
POINTS = {  # name: (bytes, status, what the message must say)
    "empty file": (b"", 400, "empty"),
    "pickled object array (NPY)": (_object_npy(), 400, "(?i)object arrays cannot be loaded"),
    "pickled object array (NPZ)": (_object_npz(), 400, "(?i)object arrays cannot be loaded"),
    "raw pickle": (pickle.dumps(Trap()), 415, "this is a Python pickle; this endpoint takes a point cloud"),
    "a PNG image": (_png_bytes(), 415, r"this is a PNG image; this endpoint takes a point cloud \(PLY, XYZ/TXT, NPY, "
                                     r"NPZ or OBJ vertices\)"),
    "a PDF": (b"%PDF-1.4\n" + b"0" * 100, 415, "this is a PDF document"),
    "a ZIP that is not an NPZ": (_zip_bytes(), 415, "this is a ZIP archive"),
    "complex dtype": (_npy((_sphere() + 1j).astype(np.complex64)), 400, "complex64 values"),
    "complex dtype in an NPZ": (_npz_bytes(points=_sphere() + 1j), 400, "complex128 values"),
    "boolean dtype": (_npy(_sphere() > 0), 400, "bool values"),
    "string dtype": (_npy(np.array([["a", "b", "c"]] * 10)), 400, "values, not real numbers"),
    "NaN coordinates": (_npy(np.vstack([_sphere(), [[np.nan, 0, 0]]])), 400, "NaN or infinite .*row 2000"),
    "infinite coordinates": (_npy(np.vstack([_sphere(), [[np.inf, 0, 0]]])), 400, "NaN or infinite"),
    "two rows, one NaN": (b"1 2 3\nnan 5 6\n", 400, "NaN or infinite coordinates \\(first at row 1\\)"),
    "a single point": (b"1 2 3\n", 400, "at least 3 points"),
    "a handful of points": (_npy(_sphere()[:99]), 400, "the scan has 99 points; completion needs at least 100"),
    "a handful once strays are dropped": (_npy(np.vstack([_sphere()[:60], _sphere()[:5] + 1e4])), 400,
                                          "has 60 points once 5 far from the rest are dropped"),
    "identical points": (_npy(np.ones((500, 3))), 400, "identical"),
    "collinear points": (_npy(np.outer(np.arange(500.0), [1, 2, 3])), 400, "on a line"),
    "collinear within 6-digit rounding": (_text(np.outer(_t, [0.001001, 0.002002, 0.003003])), 400, "on a line"),
    "collinear within rounding, irrational steps": (_text(np.stack([_t / 7, 2 * _t / 7, 3 * _t / 7 + 1], 1)), 400,
                                                    "on a line"),
    "PLY promising more vertices than it holds": (_ply(1000, 10), 400, "declares 1,000 vertices but the file holds 10"),
    "PLY declaring 10 million vertices": (_ply(10_000_000, 10), 413, "10,000,000 vertices"),
    "10 million points (NPY header)": (b"\x93NUMPY\x01\x00v\x00{'descr': '<f4', 'fortran_order': False, "
                                       b"'shape': (10000000, 3), }" + b" " * 40 + b"\n", 413, "10,000,000 rows"),
    "wrong columns": (_npy(np.ones((100, 2))), 400, "3 \\(x y z\\) or 6"),
    "binary junk": (bytes(range(256)) * 20, 415, "binary data of no format"),
    "text in no format": (b"hello, I am not a point cloud\n", 415, "text in no format"),
    "corrupt npz": (b"PK\x03\x04" + b"\x00" * 100, 400, "corrupt"),
}


@pytest.mark.parametrize("case", sorted(POINTS))
def test_bad_point_clouds(client, case):
    data, status, message = POINTS[case]
    before = set(os.listdir(tempfile.gettempdir()))
    r = client.post("/v1/complete", files={"points": ("scan.bin", data, "application/octet-stream")})
    body = _err(r, status)
    assert re.search(message, body["message"]), body["message"]
    assert not os.path.exists(MARKER)
    assert not [f for f in set(os.listdir(tempfile.gettempdir())) - before if f.startswith("aocnn-")]


CLI_CASES = {  # the same bytes under the name they claim -> what the command line says
    "pickled object array (NPY)": (".npy", "(?i)object arrays cannot be loaded"),
    "pickled object array (NPZ)": (".npz", "(?i)object arrays cannot be loaded"),
    "raw pickle": (".npy", "this is a Python pickle; a mesh .* or a point cloud .* is needed"),
    "a PNG image": (".xyz", r"this is a PNG image; a mesh \(OBJ, OFF, STL, PLY, GLB or glTF\) or a point cloud"),
    "two rows, one NaN": (".xyz", r"NaN or infinite coordinates \(first at row 1\)"),
    "collinear within 6-digit rounding": (".xyz", "on a line"),
    "collinear within rounding, irrational steps": (".txt", "on a line"),
}


@pytest.mark.parametrize("case", sorted(CLI_CASES))
def test_the_command_line_refuses_the_same_inputs_with_one_line(tmp_path, case):
    """Exit status 2, one line saying what is wrong, no output file, and nothing unpickled."""
    suffix, message = CLI_CASES[case]
    src = tmp_path / f"input{suffix}"
    src.write_bytes(POINTS[case][0])
    proc = subprocess.run([sys.executable, "-m", "model.octree", str(src), "--depth", "5", "--out",
                           str(tmp_path / "out.ply")], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert re.search(message, proc.stderr), proc.stderr
    assert not (tmp_path / "out.ply").exists() and not os.path.exists(MARKER)


def test_uploads_cannot_make_the_server_read_its_own_files(client):
    """A glTF whose buffer points at a server file, an OBJ whose material library is /dev/zero:
    nothing outside the upload is read (no hang on /dev/zero), and no server path is echoed."""
    import json as _json
    doc = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
           "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "mode": 4}]}],
           "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                          "min": [0, 0, 0], "max": [1, 1, 0]}],
           "bufferViews": [{"buffer": 0, "byteLength": 36}]}
    for uri in ("/dev/zero", "../../../../etc/hostname", "file:///etc/hostname"):
        doc["buffers"] = [{"byteLength": 36, "uri": uri}]
        r = client.post("/v1/octree?depth=4", files={"shape": ("x.gltf", _json.dumps(doc).encode())})
        body = _err(r, 400, "invalid_points")
        assert tempfile.gettempdir() not in body["message"]
    obj = b"mtllib /dev/zero\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n"
    t = time.perf_counter()
    assert client.post("/v1/octree?depth=4", files={"shape": ("x.obj", obj)}).status_code == 200
    assert time.perf_counter() - t < 10


def test_zip_bomb_npz_is_refused_from_its_directory(models_dir):
    buf = io.BytesIO()
    np.savez_compressed(buf, points=np.zeros((3_000_000, 3)))           # 72 MB unpacked, ~70 kB packed
    with make_client(models_dir, max_npz_bytes=8 << 20) as c:
        body = _err(c.post("/v1/complete", files={"points": ("s.npz", buf.getvalue())}), 413, "input_too_large")
        assert "unpacks to" in body["message"]


def test_too_many_points_and_bodies_too_large(models_dir):
    pts = _sphere(5000)
    with make_client(models_dir, max_points=1000, max_body_bytes=200_000) as c:
        _err(c.post("/v1/complete", files={"points": ("s.npy", _npy(pts))}), 413, "too_many_points")
        big = np.random.default_rng(0).integers(0, 255, (400, 400, 3), np.uint8)
        _err(c.post("/v1/image-to-shape", files={"image": ("p.png", png(big))}), 413, "body_too_large")
        _err(c.post("/v1/image-to-shape", content=b"x" * 300_000,
                    headers={"Content-Type": "multipart/form-data; boundary=xx"}), 413, "body_too_large")


def test_a_lying_content_type_or_file_name_does_not_matter(client):
    pts = _sphere(3000)
    r = client.post("/v1/complete", files={"points": ("photo.jpg", _npy(pts), "image/jpeg")})
    assert r.status_code == 200
    r = client.post("/v1/image-to-shape", files={"image": ("scan.ply", photo(), "application/x-ply")})
    assert r.status_code == 200


def test_saturation_answers_503_with_retry_after_and_slow_work_504():
    async def scenario():
        lim = Limiter(concurrency=1, queue=0, metrics=Metrics())
        slow = asyncio.ensure_future(lim.run(lambda: time.sleep(0.4), timeout=5))
        await asyncio.sleep(0.05)
        with pytest.raises(ServiceError) as busy:
            await lim.run(lambda: 1, timeout=5)
        assert busy.value.status == 503 and busy.value.headers == {"Retry-After": "1"}
        await slow
        with pytest.raises(ServiceError) as late:
            await lim.run(lambda: time.sleep(0.3), timeout=0.05)
        assert late.value.status == 504
        with pytest.raises(ServiceError) as still:                   # the timed-out work still holds its slot
            await lim.run(lambda: 7, timeout=5)
        assert still.value.status == 503
        await asyncio.sleep(0.4)
        assert await lim.run(lambda: 7, timeout=5) == 7          # and gives it back when it ends
        queued = Limiter(concurrency=1, queue=1, metrics=Metrics())
        a = asyncio.ensure_future(queued.run(lambda: time.sleep(0.2) or "a", timeout=5))
        await asyncio.sleep(0.02)
        b = asyncio.ensure_future(queued.run(lambda: "b", timeout=5))   # waits in the queue
        await asyncio.sleep(0.02)
        with pytest.raises(ServiceError):
            await queued.run(lambda: "c", timeout=5)                    # queue full
        assert await a == "a" and await b == "b"
    asyncio.run(scenario())


def test_threads_times_concurrency_never_exceed_the_cpus():
    for cpus in (1, 2, 3, 8, 64):
        for conc in (None, 1, 2, 5, 100):
            for threads in (None, 1, 4):
                c, t = plan_threads(Settings(concurrency=conc, threads=threads), cpus)
                assert c >= 1 and t >= 1 and c * t <= max(cpus, 1)


def test_startup_fails_fast_on_a_bad_bundle(models_dir, tmp_path):
    with pytest.raises(StartupError, match="does not exist"):
        Engine(Settings(models_dir=tmp_path / "none")).load()
    (tmp_path / "empty").mkdir()
    with pytest.raises(StartupError, match="holds no bundle"):
        Engine(Settings(models_dir=tmp_path / "empty")).load()
    bad = tmp_path / "bad"
    shutil.copytree(models_dir, bad)
    f = bad / "completion" / "decoder_start.onnx"
    data = bytearray(f.read_bytes())
    data[100] ^= 0xFF
    f.write_bytes(bytes(data))
    with pytest.raises(StartupError, match=r"bundle completion: .*decoder_start\.onnx: sha256"):
        Engine(Settings(models_dir=bad)).load()
    with pytest.raises(StartupError, match="sha256"):
        with make_client(bad):
            pass
    dup = tmp_path / "dup"
    shutil.copytree(models_dir, dup)
    shutil.copytree(dup / "completion", dup / "completion2")
    with pytest.raises(StartupError, match="both serve completion"):
        Engine(Settings(models_dir=dup)).load()


def test_the_service_runs_with_torch_absent(models_dir):
    done = run_without_torch(f"""
        from fastapi.testclient import TestClient
        from service.app import create_app
        from service.settings import Settings
        with TestClient(create_app(Settings(models_dir={str(models_dir)!r}))) as c:
            r = c.get("/readyz")
            assert r.status_code == 200, r.text
            pts = "\\n".join(f"{{x}} {{y}} {{(x * x + y * y) ** 0.5}}" for x in range(-20, 21) for y in range(-20, 21))
            r = c.post("/v1/octree?depth=5", files={{"shape": ("c.xyz", pts.encode())}})
            assert r.status_code == 200, r.text
        print("ok")
    """)
    assert done.returncode == 0 and done.stdout.strip().endswith("ok"), done.stderr[-2000:]


def test_python_m_service_exits_2_with_one_line_on_bad_settings_or_bundles(tmp_path, capsys, monkeypatch):
    from service.__main__ import main

    assert main(["--models-dir", str(tmp_path / "none")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "does not exist" in err
    monkeypatch.setenv("AOCNN_MAX_POINTS", "many")
    assert main([]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "AOCNN_MAX_POINTS=many is not valid" in err and "an integer >= 3" in err
    monkeypatch.delenv("AOCNN_MAX_POINTS")
    monkeypatch.setenv("AOCNN_MAX_OCTREE_DEPTH", "13")
    assert main([]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "AOCNN_MAX_OCTREE_DEPTH=13" in err and "<= 12" in err
    monkeypatch.setenv("AOCNN_MAX_OCTREE_DEPTH", "12")      # the octree core's deepest build is allowed
    assert main(["--models-dir", str(tmp_path / "none"), "--port", "70000"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--port 70000 is not valid" in err and "<= 65535" in err
    assert main(["--warm-up", "--models-dir", str(tmp_path / "none")]) == 2      # nothing to warm up
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "does not exist" in err


def test_python_m_service_warm_up_loads_warms_and_exits_without_serving(models_dir, capsys):
    from service.__main__ import main

    assert main(["--warm-up", "--models-dir", str(models_dir)]) == 0
    out = capsys.readouterr().out.strip()
    assert re.fullmatch(r"warmed up [a-z, -]+ in \d+\.\d s", out), out


def test_one_source_for_each_limit_and_the_readme_table_is_made_from_it(client):
    from model.octree.build import MAX_BUILD_DEPTH, build_octree  # noqa: F401
    from service.settings import settings_table

    readme = (ROOT / "README.md").read_text()
    assert settings_table() in readme, "README's settings table differs from python -m service --settings"
    field = Settings.model_fields["max_octree_depth"]
    assert [getattr(m, "le", None) for m in field.metadata if hasattr(m, "le")] == [MAX_BUILD_DEPTH]
    assert Settings(max_octree_depth=MAX_BUILD_DEPTH).max_octree_depth == MAX_BUILD_DEPTH
    body = _err(client.post("/v1/octree?depth=9", files={"shape": ("s.xyz", b"0 0 0")}), 422, "invalid_depth")
    assert "AOCNN_MAX_OCTREE_DEPTH" in body["hint"] and "at most 8" in body["message"]
    _err(client.post(f"/v1/octree?depth={MAX_BUILD_DEPTH + 1}", files={"shape": ("s.xyz", b"0 0 0")}), 422,
         "invalid_request")
