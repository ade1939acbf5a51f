"""import rose_usd stays light (newton's test_lazy_imports.py is the model).

``ROSE_TEST_PYTHON`` names another interpreter to check (CI: a fresh venv with the built wheel)."""

import os
import subprocess
import sys

HEAVY = ("mitsuba", "drjit", "warp", "newton", "open3d", "ray", "torch")


def test_import_loads_no_heavy_module(tmp_path):
    """Importing the package, its registry, pipeline, API and CLI loads none of the heavy engines."""
    code = (
        "import sys, rose_usd, rose_usd.registry, rose_usd.pipeline, rose_usd.api, rose_usd.cli\n"
        "rose_usd.reconstruct, rose_usd.STAGES\n"
        f"print([m for m in {HEAVY!r} if m in sys.modules])\n"
        "print(rose_usd.__file__)\n"
    )
    python = os.environ.get("ROSE_TEST_PYTHON", sys.executable)
    # run outside the checkout, so that the interpreter imports its installed rose_usd
    out = subprocess.run([python, "-c", code], capture_output=True, text=True, check=True, cwd=tmp_path)
    heavy, where = out.stdout.strip().splitlines()
    assert heavy == "[]", out.stdout + out.stderr
    print(f"imported {where}")
