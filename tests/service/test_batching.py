"""Dynamic batching: concurrent requests within the window run as one batch, each gets its own
answer (or its own error), batches respect max_batch, and batched answers equal single ones."""

from __future__ import annotations

import asyncio
import io
from concurrent.futures import ThreadPoolExecutor

import pytest
import trimesh

from service.batching import Batcher
from service.errors import ServiceError
from service.limiter import Limiter
from service.metrics import Metrics

from .conftest import make_client
from .test_api import photo


def test_requests_within_the_window_share_one_batch_and_keep_their_own_errors():
    calls = []

    def run(requests):
        calls.append(list(requests))
        return [ServiceError("invalid_points", f"bad {r}", "fix it") if r < 0 else r * 10 for r in requests]

    async def scenario():
        b = Batcher(run, Limiter(1, 4, Metrics()), window_s=0.05, max_batch=3, timeout=5)
        results = await asyncio.gather(*[b.submit(r) for r in (1, -2, 3, 4)], return_exceptions=True)
        assert results[0] == 10 and results[2] == 30 and results[3] == 40
        assert isinstance(results[1], ServiceError) and results[1].message == "bad -2"
        assert [len(c) for c in calls] == [3, 1]                 # max_batch 3, then the rest
        calls.clear()
        off = Batcher(run, Limiter(1, 4, Metrics()), window_s=0, max_batch=8, timeout=5)
        assert await asyncio.gather(off.submit(1), off.submit(2)) == [10, 20]
        assert [len(c) for c in calls] == [1, 1]                 # window 0: no batching
    asyncio.run(scenario())


def test_a_failing_batch_fails_each_of_its_requests_once():
    def run(requests):
        raise RuntimeError("boom")

    async def scenario():
        b = Batcher(run, Limiter(1, 4, Metrics()), window_s=0.02, max_batch=8, timeout=5)
        results = await asyncio.gather(b.submit(1), b.submit(2), return_exceptions=True)
        assert all(isinstance(r, RuntimeError) for r in results)
    asyncio.run(scenario())


@pytest.mark.parametrize("window", [0, 300])
def test_concurrent_requests_get_the_same_meshes_batched_or_not(models_dir, window):
    images = [photo(seed) for seed in range(4)]
    with make_client(models_dir) as single:
        want = [single.post("/v1/image-to-shape?format=ply", files={"image": ("p.png", im)}) for im in images]
    with make_client(models_dir, batch_window_ms=window, max_batch=4) as c:
        def post(im):
            return c.post("/v1/image-to-shape?format=ply", files={"image": ("p.png", im)})
        with ThreadPoolExecutor(4) as pool:
            got = list(pool.map(post, images + [b"not an image"]))
        text = c.get("/metrics").text
    assert got[-1].status_code == 415                       # the bad one fails alone
    for g, w in zip(got, want):
        assert g.status_code == 200 == w.status_code
        a = trimesh.load(io.BytesIO(g.content), file_type="ply", process=False)
        b = trimesh.load(io.BytesIO(w.content), file_type="ply", process=False)
        assert a.area == pytest.approx(b.area, rel=1e-3)
        assert g.headers["x-octree-leaves"] == w.headers["x-octree-leaves"]
    batches = float(text.split("aocnn_batch_size_count ")[1].split()[0])
    assert float(text.split("aocnn_batch_size_sum ")[1].split()[0]) == 5
    assert batches == 5 if window == 0 else batches < 5     # one batch per request, or shared batches


def test_a_guided_completion_answers_each_scan_with_its_own_features_batched_or_not(models_dir, exported, clouds,
                                                                                  tmp_path):
    """A guided completion bundle (output-guided skip connections) batches scans: the decode of
    each group (keep_scan true / false) reads only its own shapes' encoder features, so batched
    answers equal single ones and the bundle's own decode of the scan, whose graphs are torch's."""
    import shutil

    import numpy as np
    import torch

    from export.bundle import load_bundle
    from export.parity import decoder_parity
    from export.runtime import Runtime
    from model.networks import TorchSteps
    from model.octree import scan_octree, validate
    from model.octree.batch import split_octree

    from .test_api import _npy, partial_cloud

    model, cfg, bundle = exported("completion-guided")
    root = tmp_path / "models"
    shutil.copytree(models_dir, root)
    shutil.rmtree(root / "completion")
    shutil.copytree(bundle, root / "completion")
    base = partial_cloud(clouds)[::4]
    scans = [base, base[base[:, 1] < np.quantile(base[:, 1], 0.8)], base[::2] * 1.5 + 0.3]
    queries = ["keep_scan=false", "keep_scan=true", "keep_scan=false"]
    tree = scan_octree(validate(scans[0], None), cfg.depth)
    runtime = Runtime(load_bundle(bundle), threads=1)
    latent, guide = runtime.encode_scan(tree)
    own = split_octree(runtime.decode(latent, guide=guide), neighbors=False)[0]
    # the graphs are torch's, step by step with each one's own encoder features (a random decoder
    # has near-tied statuses: whole decodes may differ on another CPU while every graph agrees)
    with torch.no_grad():
        latent_t, guide_t = model.encode_octree(tree)
    dec = model.decoder
    report, _ = decoder_parity(TorchSteps(dec), runtime.steps(), latent_t.numpy(), dec.full_depth, dec.adaptive_depth,
                               other_latent=latent, guides=(guide_t, guide))
    assert report.ok, report.summary()
    with make_client(root) as single:
        want = [single.post(f"/v1/complete?format=ply&{q}", files={"points": ("s.npy", _npy(s))})
                for s, q in zip(scans, queries)]
    assert want[0].headers["x-octree-leaves"] == ",".join(f"{d}:{n}" for d, n in enumerate(own.leaves_per_depth()) if n)
    with make_client(root, batch_window_ms=300, max_batch=4) as c:
        with ThreadPoolExecutor(3) as pool:
            got = list(pool.map(lambda a: c.post(f"/v1/complete?format=ply&{a[1]}",
                                                 files={"points": ("s.npy", _npy(a[0]))}), zip(scans, queries)))
        text = c.get("/metrics").text
    assert float(text.split("aocnn_batch_size_count ")[1].split()[0]) < 3      # shared batches
    for g, w in zip(got, want):
        assert g.status_code == 200 == w.status_code, g.text
        assert g.headers["x-octree-leaves"] == w.headers["x-octree-leaves"]
    assert len({w.headers["x-octree-leaves"] for w in want}) == 3
