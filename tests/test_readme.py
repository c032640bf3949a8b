"""The README's cheap commands, run as written: every ``curl`` example against the service on the
shipped bundles, the octree command line, the bundle check, and the octree's Python example.
They run in a scratch folder that sees the checkout's ``examples/`` and ``models/``, so nothing is
written into the checkout; ``localhost:8000`` becomes the test server's address."""

from __future__ import annotations

import json
import os
import re
import shutil
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()
CHEAP = ("curl ", "python -m model.octree ", "python -m export --verify ")


def blocks(language: str) -> list[str]:
    return re.findall(rf"```{language}\n(.*?)```", README, re.S)


def commands() -> list[str]:
    """The README's shell commands that are cheap to run, continuation lines joined, comments cut."""
    out = []
    for block in blocks("bash"):
        for line in block.replace("\\\n", " ").splitlines():
            line = re.sub(r"\s{2,}#.*$", "", line).strip()
            if line.startswith(CHEAP):
                out.append(line)
    return out


@pytest.fixture(scope="module")
def scratch(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("readme")
    for name in ("examples", "models"):
        (folder / name).symlink_to(ROOT / name)
    return folder


def environment() -> dict:
    """``python`` is this test's interpreter (the README's commands run in its environment)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    return env


@pytest.fixture(scope="module")
def service(scratch):
    """``python -m service`` on the shipped bundles, on a free port, until the tests end."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = subprocess.Popen([sys.executable, "-m", "service", "--port", str(port)], cwd=ROOT, env=environment(),
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 180
    while True:
        assert proc.poll() is None, proc.stderr.read().decode()[-2000:]
        try:
            if urllib.request.urlopen(f"http://127.0.0.1:{port}/readyz", timeout=2).status == 200:
                break
        except OSError:
            pass
        assert time.monotonic() < deadline, "the service did not become ready"
        time.sleep(0.5)
    yield f"127.0.0.1:{port}"
    proc.terminate()
    proc.wait(30)


def test_the_readme_has_the_commands_it_promises():
    found = commands()
    assert sum(c.startswith("curl ") for c in found) >= 8
    assert any(c.startswith("python -m model.octree examples/") for c in found)
    assert "../shared" not in README.split("## The octree from the command line")[1].split("## ")[0]


@pytest.mark.parametrize("command", [c for c in commands() if c.startswith("curl ")])
def test_curl_examples_answer_with_what_they_promise(command, scratch, service):
    if shutil.which("curl") is None:
        pytest.skip("curl is not installed (apt-get install curl)")
    run = subprocess.run(command.replace("localhost:8000", service), shell=True, cwd=scratch, env=environment(),
                         capture_output=True, timeout=300)
    assert run.returncode == 0, run.stderr
    target = re.search(r"-o (\S+)", command)
    if target:
        data = (scratch / target.group(1)).read_bytes()
        assert not data.startswith(b'{"error"'), data[:300]
        if "debug=mask" in command:                  # the object's mask: a greyscale PNG of the photo's size
            from PIL import Image
            photo = Image.open(scratch / re.search(r"image=@(\S+)", command).group(1))
            mask = Image.open(scratch / target.group(1))
            assert mask.mode == "L" and mask.size == photo.size and 0 < np.asarray(mask).mean() < 200
        else:
            assert len(data) > 1000 and (data[:4] == b"glTF" or data.startswith(b"# adaptive-ocnn")), data[:40]
    elif "/metrics" in command:
        assert b"aocnn_requests_total" in run.stdout
    else:
        body = json.loads(run.stdout)
        assert "error" not in body, body
        assert body.get("ready", True) and (body.get("top") or body.get("models") or body.get("ready"))


@pytest.mark.parametrize("command", [c for c in commands() if c.startswith("python")])
def test_command_lines_run_as_written(command, scratch):
    run = subprocess.run(command, shell=True, cwd=scratch, env=environment(), capture_output=True, text=True,
                         timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
    for out in re.findall(r"--(?:out|stats) (\S+)", command):
        assert (scratch / out).stat().st_size > 100


def test_the_octree_python_example_runs(scratch):
    example = next(b for b in blocks("python") if "build_octree" in b)
    run = subprocess.run([sys.executable, "-c", example], cwd=scratch, env=environment(), capture_output=True,
                         text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    assert (scratch / "patches.ply").stat().st_size > 1000


def test_the_layout_section_names_the_tree_as_it_is():
    """Every path of the README's layout table exists, and every top-level folder and every
    package of ``model/`` has a row (the table is the tree, not a memory of it)."""
    section = README.split("## Layout", 1)[1].split("\n## ", 1)[0]
    named = set(re.findall(r"^\| (.+?) \|", section, re.M)) - {"path", "---"}
    paths = {p.strip("`").rstrip("/") for cell in named for p in re.findall(r"`([^`]+)`", cell)}
    assert paths and all((ROOT / p).exists() for p in paths), sorted(p for p in paths if not (ROOT / p).exists())
    tracked = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True).stdout.split()
    folders = {f.split("/")[0] for f in tracked if "/" in f and not f.startswith(".")}
    packages = {str(p.parent.relative_to(ROOT)) for p in (ROOT / "model").glob("*/__init__.py")}
    assert folders | packages <= paths, sorted((folders | packages) - paths)
