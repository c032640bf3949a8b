"""GLB and glTF answers pass the Khronos glTF validator (npm gltf-validator, run by node)."""

from __future__ import annotations

import json
import shutil
import subprocess

import pytest

from .test_api import photo

VALIDATE_JS = """
const validator = require('gltf-validator');
const data = new Uint8Array(require('fs').readFileSync(process.argv[2]));
validator.validateBytes(data).then(r => console.log(JSON.stringify(r.issues)))
  .catch(e => { console.error(String(e)); process.exit(1); });
"""


@pytest.fixture(scope="session")
def validator(tmp_path_factory):
    if not (shutil.which("node") and shutil.which("npm")):
        pytest.skip("node and npm are needed to run the Khronos glTF validator")
    root = tmp_path_factory.mktemp("gltf-validator")
    done = subprocess.run(["npm", "install", "--no-audit", "--no-fund", "--silent", "gltf-validator@2.0.0-dev.3.10"],
                          cwd=root, capture_output=True, text=True, timeout=300)
    if done.returncode != 0:
        pytest.skip(f"npm could not install gltf-validator: {done.stderr.strip()[-300:]}")
    (root / "validate.js").write_text(VALIDATE_JS)
    return root


@pytest.mark.parametrize("surface", ["watertight", "patches"])
@pytest.mark.parametrize("fmt", ["glb", "gltf"])
@pytest.mark.parametrize("color", [False, True])
def test_meshes_pass_the_khronos_validator_without_errors_or_warnings(client, validator, tmp_path, fmt, color, surface):
    r = client.post(f"/v1/image-to-shape?format={fmt}&color_by_depth={str(color).lower()}&surface={surface}",
                    files={"image": ("p.png", photo())})
    assert r.status_code == 200
    path = tmp_path / f"out.{fmt}"
    path.write_bytes(r.content)
    done = subprocess.run(["node", str(validator / "validate.js"), str(path)], capture_output=True, text=True,
                          timeout=60, cwd=validator)
    assert done.returncode == 0, done.stderr
    issues = json.loads(done.stdout)
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"][:5]
