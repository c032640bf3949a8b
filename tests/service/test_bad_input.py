"""Hostile and broken inputs, by class: each gets a 4xx JSON error saying what is wrong, never a
500, a hang or a file left behind; overload gets 503 with Retry-After; bad bundles stop startup."""

from __future__ import annotations

import asyncio
import io
import os
import pickle
import shutil
import tempfile
import time

import numpy as np
import pytest
from PIL import Image

from service.engine import Engine, Limiter, StartupError, plan_threads
from service.errors import APIError
from service.metrics import Metrics
from service.settings import Settings

from ..torchless import run_without_torch
from .conftest import make_client
from .test_api import _npy, png, photo


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
    "fully transparent": (png(np.zeros((20, 20, 4), np.uint8)), 400, "invalid_image"),
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


def _npz_bytes(**arrays) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def _object_npy() -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.array([{"a": 1}, None], dtype=object), allow_pickle=True)
    return buf.getvalue()


class Boom:
    def __reduce__(self):
        return (os.system, ("touch /tmp/aocnn-pwned",))


def _ply(n_declared: int, n_given: int) -> bytes:
    head = (f"ply\nformat ascii 1.0\nelement vertex {n_declared}\nproperty float x\nproperty float y\n"
            f"property float z\nend_header\n")
    return (head + "".join(f"{i} {i % 7} {i % 3}\n" for i in range(n_given))).encode()


def _sphere(n=2000, seed=0):
    p = np.random.default_rng(seed).normal(size=(n, 3))
    return p / np.linalg.norm(p, axis=1, keepdims=True)


POINTS = {
    "empty file": (b"", 400),
    "pickled object array": (_object_npy(), 400),
    "raw pickle": (pickle.dumps(Boom()), 400),
    "complex dtype": (_npy((_sphere() + 1j).astype(np.complex64)), 400),
    "complex dtype in an NPZ": (_npz_bytes(points=_sphere() + 1j), 400),
    "boolean dtype": (_npy(_sphere() > 0), 400),
    "string dtype": (_npy(np.array([["a", "b", "c"]] * 10)), 400),
    "NaN coordinates": (_npy(np.vstack([_sphere(), [[np.nan, 0, 0]]])), 400),
    "infinite coordinates": (_npy(np.vstack([_sphere(), [[np.inf, 0, 0]]])), 400),
    "a single point": (b"1 2 3\n", 400),
    "identical points": (_npy(np.ones((500, 3))), 400),
    "collinear points": (_npy(np.outer(np.arange(500.0), [1, 2, 3])), 400),
    "PLY promising more vertices than it holds": (_ply(1000, 10), 400),
    "PLY declaring 10 million vertices": (_ply(10_000_000, 10), 413),
    "10 million points (NPY header)": (b"\x93NUMPY\x01\x00v\x00{'descr': '<f4', 'fortran_order': False, "
                                       b"'shape': (10000000, 3), }" + b" " * 40 + b"\n", 413),
    "wrong columns": (_npy(np.ones((100, 2))), 400),
    "binary junk": (bytes(range(256)) * 20, 400),
    "corrupt npz": (b"PK\x03\x04" + b"\x00" * 100, 400),
}


@pytest.mark.parametrize("case", sorted(POINTS))
def test_bad_point_clouds(client, case):
    data, status = POINTS[case]
    before = set(os.listdir(tempfile.gettempdir()))
    r = client.post("/v1/complete", files={"points": ("scan.bin", data, "application/octet-stream")})
    _err(r, status)
    assert not os.path.exists("/tmp/aocnn-pwned")
    assert not [f for f in set(os.listdir(tempfile.gettempdir())) - before if f.startswith("aocnn-")]


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
        with pytest.raises(APIError) as busy:
            await lim.run(lambda: 1, timeout=5)
        assert busy.value.status == 503 and busy.value.headers == {"Retry-After": "1"}
        await slow
        with pytest.raises(APIError) as late:
            await lim.run(lambda: time.sleep(0.3), timeout=0.05)
        assert late.value.status == 504
        with pytest.raises(APIError) as still:                   # the timed-out work still holds its slot
            await lim.run(lambda: 7, timeout=5)
        assert still.value.status == 503
        await asyncio.sleep(0.4)
        assert await lim.run(lambda: 7, timeout=5) == 7          # and gives it back when it ends
        queued = Limiter(concurrency=1, queue=1, metrics=Metrics())
        a = asyncio.ensure_future(queued.run(lambda: time.sleep(0.2) or "a", timeout=5))
        await asyncio.sleep(0.02)
        b = asyncio.ensure_future(queued.run(lambda: "b", timeout=5))   # waits in the queue
        await asyncio.sleep(0.02)
        with pytest.raises(APIError):
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
    assert err.count("\n") == 1 and "max_points" in err
