"""Mesh operations several stages share: validity checks, CGAL wrapping, color transfer and
texture baking. Neutral ground: it imports no stage package."""
