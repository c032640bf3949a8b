"""Run Python code in a subprocess where importing torch fails (the serving side must not need it)."""

from __future__ import annotations

import subprocess
import sys
import textwrap

BLOCK_TORCH = textwrap.dedent("""
    import sys, importlib.abc
    class NoTorch(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name == "torch" or name.startswith("torch."):
                raise ImportError("torch is not installed here")
    sys.meta_path.insert(0, NoTorch())
""")


def run_without_torch(code: str, timeout: float = 180) -> subprocess.CompletedProcess:
    """``code`` (dedented) after a finder that makes ``import torch`` raise ImportError."""
    script = BLOCK_TORCH + textwrap.dedent(code) + '\nassert "torch" not in sys.modules\n'
    return subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=timeout)
