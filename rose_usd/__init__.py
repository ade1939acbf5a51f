"""rose_usd: a casual video of a person moving an object -> a simulator-ready OpenUSD bundle.

Importing the package registers rose's codeless USD schemas (``schemas/``) with OpenUSD and
nothing heavier: mitsuba, drjit, warp, newton and open3d are imported only where they are used.
"""

from rose_usd.errors import RoseError
from rose_usd.usd.schema import register_schemas

__version__ = "0.1.0"
__all__ = ["RoseError", "__version__"]

register_schemas()
