"""import rose_usd stays light (newton's test_lazy_imports.py is the model)."""

import subprocess
import sys

HEAVY = ("mitsuba", "drjit", "warp", "newton", "open3d", "ray", "torch")


def test_import_loads_no_heavy_module():
    """Importing the package, its registry, pipeline and CLI loads none of the heavy engines."""
    code = (
        "import sys, rose_usd, rose_usd.registry, rose_usd.pipeline, rose_usd.cli\n"
        f"print([m for m in {HEAVY!r} if m in sys.modules])\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout + out.stderr
