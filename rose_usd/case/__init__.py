"""Input cases: the folder (or video) layout of architecture.md section 3, validated up front."""

from rose_usd.case.layout import Case, load_case

__all__ = ["Case", "load_case"]
