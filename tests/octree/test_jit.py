"""The kernels' disk cache on an install that cannot write beside its sources."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
PROBE = ("import os; real = os.access; "
         "os.access = (lambda p, m: False if {readonly} and 'octree' in str(p) and m == os.W_OK else real(p, m)); "
         "from numba.core import config; import model.octree.jit; print(repr(config.CACHE_DIR))")


def cache_dir(readonly: bool, env_dir: str | None, extra: dict[str, str] | None = None) -> str:
    env = {**{k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}, **(extra or {})}
    if env_dir is not None:
        env["NUMBA_CACHE_DIR"] = env_dir
    out = subprocess.run([sys.executable, "-c", PROBE.format(readonly=readonly)], capture_output=True, text=True,
                         cwd=REPO, env=env, timeout=120)
    assert out.returncode == 0, out.stderr[-1500:]
    return eval(out.stdout.strip().splitlines()[-1])


def test_a_read_only_install_caches_in_the_temporary_directory():
    assert cache_dir(True, None) == os.path.join(tempfile.gettempdir(), f"aocnn-numba-{os.getuid()}")


def test_a_read_only_install_starts_its_cache_from_the_seed_an_image_build_compiled(tmp_path):
    """``AOCNN_NUMBA_SEED``: the temporary cache starts as a copy of it (the image's kernels, compiled
    at its build), once: a cache already there is left as it is."""
    seed = tmp_path / "seed" / "app" / "model"
    seed.mkdir(parents=True)
    (seed / "kernel.nbi").write_bytes(b"index")
    env = {"AOCNN_NUMBA_SEED": str(tmp_path / "seed"), "TMPDIR": str(tmp_path)}
    cache = Path(cache_dir(True, None, env))
    assert cache.parent == tmp_path and (cache / "app" / "model" / "kernel.nbi").read_bytes() == b"index"
    (cache / "app" / "model" / "kernel.nbi").write_bytes(b"compiled here")
    assert cache_dir(True, None, env) == str(cache)
    assert (cache / "app" / "model" / "kernel.nbi").read_bytes() == b"compiled here"
    assert not list(tmp_path.glob("*.part-*"))


def test_a_writable_install_and_a_chosen_folder_are_left_alone():
    assert cache_dir(False, None) == ""
    assert cache_dir(True, "/somewhere/else") == "/somewhere/else"


FUSED = ("vfmadd", "vfmsub", "vfnmadd", "vfnmsub", "fmadd", "fmsub", "fmla", "fmls")
"""Fused multiply-add instructions (x86 FMA3, AArch64): one rounding where the k-d tree and NumPy
round twice."""
KERNELS = """
import numba, numpy as np, warnings
warnings.simplefilter("ignore")
from model.octree import build, build_octree, fuse, geometry, keys, knn, orient, patch_error, patches, planes, probe_search
from model.octree import pointcloud, segments, symmetry
from model.octree.pointcloud import estimate_normals
from model.octree.symmetry import find_mirror
from model.surface import clusters, watertight_mesh
from model.image import frame, mask, resample
frame.object_box(np.full((8, 8, 4), 255, np.uint8))
mask.bilinear_blend(np.ones((16, 16), np.float32), np.ones((16, 16), np.float32), np.ones((40, 30), np.float32))
mask.mask_input(np.zeros((200, 300, 4), np.uint8), mask.MaskSpec())        # across first, then down first
mask.mask_input(np.zeros((400, 130, 3), np.uint8), mask.MaskSpec())
frame.composite(np.zeros((4, 4, 4), np.uint8), (1, 2, 3)); mask.mask_confidence(np.eye(20, dtype=np.float32))
p = np.random.default_rng(0).random((3000, 3))
estimate_normals(p); find_mirror(p); t = build_octree((p, None), 6)
fuse.keep_scan(t, build_octree((p[:1500], None), 6))
patches.patch_mesh(t)
s = np.random.default_rng(1).normal(size=(20000, 3))
s /= np.linalg.norm(s, axis=1, keepdims=True)
watertight_mesh(build_octree((s, s.copy()), 5, neighbors=False))

@numba.njit(fastmath=True)
def contracted(a, b, c):      # the detector's own check: asked to, the compiler fuses this
    s = 0.0
    for i in range(len(a)):
        s += a[i] * b[i] + c[i]
    return s

x = np.ones(8)
contracted(x, x, x)
kernels = [f for m in (knn, probe_search, orient, geometry, clusters, fuse, mask, build, patch_error, segments, patches,
                        planes, symmetry, keys, frame, pointcloud, resample) for f in vars(m).values()
           if hasattr(f, "inspect_asm")]
for f in kernels + [contracted]:
    for sig in f.signatures:
        print("=== " + f.py_func.__name__)
        print(f.inspect_asm(sig).lower())
"""


def test_no_kernel_fuses_a_multiply_and_an_add(tmp_path):
    """The kernels reproduce the k-d tree's and NumPy's arithmetic bit for bit on any CPU only if
    the compiler keeps every product rounded before it is added (numba contracts nothing unless
    asked to); compiled afresh, their machine code holds no fused multiply-add, where a function
    compiled with fastmath on this CPU does (when the CPU has the instruction)."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}          # a fresh compile: its code can be read
    out = subprocess.run([sys.executable, "-c", KERNELS], capture_output=True, text=True, cwd=REPO, env=env,
                         timeout=600)
    assert out.returncode == 0, out.stderr[-1500:]
    listings: dict[str, str] = {}
    for part in out.stdout.split("=== ")[1:]:
        name, _, asm = part.partition("\n")
        listings[name] = listings.get(name, "") + asm
    assert {"_query", "_within", "_grid_probes", "_edge_probes", "covariance_rows", "_cube_polygons",
            "_nearest_on_fans", "_walk", "_blend", "_eigen_vectors", "_plane_normals", "_polygon_distance",
            "_place_planes", "_point_distances", "_segment_sums", "_write_patches", "radix_order",
            "sorted_payloads", "spanning_tree", "cell_keys", "_differing_bounds", "distances_from", "_across", "_down",
            "_fill_level", "_normalised", "_composite", "_edge_band"} <= set(listings)
    fused = {name: [op for op in FUSED if op in asm] for name, asm in listings.items()}
    assert not any(ops for name, ops in fused.items() if name != "contracted"), fused
    cpu = Path("/proc/cpuinfo").read_text() if Path("/proc/cpuinfo").exists() else ""
    if " fma " in cpu or " asimd" in cpu:                     # the CPU has the instruction: it is seen
        assert fused["contracted"], "the detector did not see the fused multiply-add it was shown"
